"""Regenerate the synthetic-scene pictures in docs/images/ (run from the repository root).

    python docs/scripts/make_synthetic_figures.py

Writes synthetic_frames.png (colour and depth of three frames of the default sequence),
synthetic_depth_noise.png (clean / Gaussian / sensor-like depth of one frame) and synthetic_path.png
(top-down room layout with the camera loop).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from slam.data import ReplicaDataset  # noqa: E402
from slam.data.synthetic import ROOM_MAX, ROOM_MIN, SynthConfig, build_scene, camera_path, generate  # noqa: E402

OUT = ROOT / "docs" / "images"


def frames_figure(seq: Path) -> None:
    ds = ReplicaDataset(seq)
    idx = [0, len(ds) // 2, len(ds) - 1]
    fig, axes = plt.subplots(2, 3, figsize=(11, 5.6), dpi=110)
    for col, i in enumerate(idx):
        f = ds[i]
        axes[0, col].imshow(f.color.numpy())
        axes[0, col].set_title(f"frame {i}: colour", fontsize=9)
        im = axes[1, col].imshow(f.depth.numpy(), cmap="turbo", vmin=0.4, vmax=4.0)
        axes[1, col].set_title(f"frame {i}: depth (m)", fontsize=9)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[1, :].tolist(), fraction=0.02, pad=0.01, label="depth (m)")
    k = ds.intrinsics
    fig.suptitle(f"default synthetic sequence ({len(ds)} frames, {k.width}x{k.height}, fx = {k.fx:g})", fontsize=10)
    fig.savefig(OUT / "synthetic_frames.png", bbox_inches="tight")
    plt.close(fig)


def noise_figure(tmp: Path) -> None:
    base = dict(frames=1, height=240, width=320)
    variants = [
        ("exact depth", SynthConfig(**base)),
        ("Gaussian, sigma = 1 cm", SynthConfig(**base, depth_noise_sigma=0.01)),
        ("sensor-like (noise + holes)", SynthConfig(**base, sensor_holes=True)),
    ]
    fig, axes = plt.subplots(1, 4, figsize=(14, 2.9), dpi=110)
    for k, (title, cfg) in enumerate(variants):
        f = ReplicaDataset(generate(tmp / f"n{k}", cfg))[0]
        if k == 0:
            axes[0].imshow(f.color.numpy())
            axes[0].set_title("colour (320x240)", fontsize=9)
        d = f.depth.numpy().copy()
        d[d == 0] = np.nan
        axes[k + 1].imshow(d, cmap="turbo", vmin=0.4, vmax=4.0)
        axes[k + 1].set_title(title + ("; holes white" if k == 2 else ""), fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.savefig(OUT / "synthetic_depth_noise.png", bbox_inches="tight")
    plt.close(fig)


def path_figure() -> None:
    scene = build_scene(0)
    fig, ax = plt.subplots(figsize=(5.2, 5.2), dpi=110)
    ax.add_patch(plt.Rectangle(ROOM_MIN[:2], *(ROOM_MAX - ROOM_MIN)[:2], fill=False, lw=2))
    for bmin, bmax, _ in scene.boxes:
        ax.add_patch(plt.Rectangle(bmin[:2], *(bmax - bmin)[:2], color="0.6", alpha=0.6))
    for c, r, _ in scene.spheres:
        ax.add_patch(plt.Circle(c[:2], r, color="tab:blue", alpha=0.5))
    for cxy, r, _, _, _ in scene.cylinders:
        ax.add_patch(plt.Circle(cxy, r, color="tab:orange", alpha=0.6))
    full = camera_path(SynthConfig(frames=400))
    dflt = camera_path(SynthConfig())
    ax.plot(full[:, 0, 3], full[:, 1, 3], "--", color="0.5", lw=1, label="full loop (400 frames)")
    ax.plot(dflt[:, 0, 3], dflt[:, 1, 3], color="tab:red", lw=2, label=f"default ({len(dflt)} frames)")
    for p in dflt[::20]:
        ax.arrow(p[0, 3], p[1, 3], 0.25 * p[0, 2], 0.25 * p[1, 2], head_width=0.05, color="tab:red")
    ax.set_xlim(-2.1, 2.1)
    ax.set_ylim(-2.1, 2.1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("room layout (top view) and camera path; arrows: viewing direction", fontsize=9)
    fig.savefig(OUT / "synthetic_path.png", bbox_inches="tight")
    plt.close(fig)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        frames_figure(generate(tmp / "default", SynthConfig()))
        noise_figure(tmp)
    path_figure()
    print("wrote", *sorted(p.name for p in OUT.glob("synthetic_*.png")))


if __name__ == "__main__":
    main()
