"""Writing a sequence to disk in the Replica layout, and the cached default sequence."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from slam.data.synthetic.camera import camera_path
from slam.data.synthetic.config import SynthConfig
from slam.data.synthetic.mesh import scene_mesh
from slam.data.synthetic.render import render_frame, sensor_depth
from slam.data.synthetic.scene import build_scene
from slam.errors import SlamInputError

log = logging.getLogger("slam.data.synthetic")

#: bump when the output of :func:`generate` changes for the same config, so caches regenerate
GENERATOR_VERSION = 3
#: the Replica depth PNG scale: metres = value / 6553.5 (65535 <-> 10 m, 0.15 mm steps)
DEPTH_SCALE = 6553.5


def _config_record(cfg: SynthConfig) -> dict:
    return {"generator_version": GENERATOR_VERSION, "config": dataclasses.asdict(cfg)}


def generate(out_dir, cfg: SynthConfig | None = None, *, overwrite: bool = True) -> Path:
    """Render the sequence and write it in the Replica layout into ``out_dir``; returns ``out_dir``.

    Files: ``results/frame%06d.png`` (8-bit RGB, lossless), ``results/depth%06d.png`` (uint16, metres *
    6553.5, 0 = hole), ``traj.txt`` (16 floats per line, row-major camera-to-world, OpenCV axes),
    ``mesh.ply`` (ground truth), ``cam.json`` (intrinsics, depth scale), ``synth.json`` (config).
    Deterministic: the same config gives byte-identical images.
    """
    import imageio.v3 as iio

    cfg = cfg or SynthConfig()
    cfg.validate()
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise SlamInputError(f"{out}: folder exists and is not empty")
        if not (out / "synth.json").exists():
            raise SlamInputError(f"{out}: folder exists, is not empty and is not a synthetic sequence; refusing to overwrite")
        shutil.rmtree(out / "results", ignore_errors=True)
    t0 = time.perf_counter()
    (out / "results").mkdir(parents=True, exist_ok=True)
    scene = build_scene(cfg.seed)
    intr = cfg.intrinsics()
    poses = camera_path(cfg)
    for i, pose in enumerate(poses):
        color, depth, cos, _ = render_frame(scene, pose, intr, cfg.supersample)
        rng = np.random.default_rng([cfg.seed, 2, i])
        if cfg.sensor_holes:
            depth = sensor_depth(depth, cos, rng)
        if cfg.depth_noise_sigma > 0:
            valid = depth > 0
            depth = np.where(valid, depth + rng.normal(0.0, cfg.depth_noise_sigma, depth.shape), 0.0)
        if cfg.color_noise_sigma > 0:
            color = color + rng.normal(0.0, cfg.color_noise_sigma, color.shape)
        col8 = np.round(np.clip(color, 0, 1) * 255).astype(np.uint8)
        d16 = np.round(np.clip(depth, 0, 65535 / DEPTH_SCALE) * DEPTH_SCALE).astype(np.uint16)
        # low zlib effort: 3x faster writes for ~10 % larger files
        iio.imwrite(out / "results" / f"frame{i:06d}.png", col8, compress_level=1)
        iio.imwrite(out / "results" / f"depth{i:06d}.png", d16, compress_level=1)
    np.savetxt(out / "traj.txt", poses.reshape(len(poses), 16), fmt="%.10f")
    mesh = scene_mesh(scene)
    mesh.export(out / "mesh.ply")
    cam = {**intr.as_dict(), "depth_scale": DEPTH_SCALE, "name": f"synthetic_seed{cfg.seed}",
           "axes": "OpenCV (x right, y down, z forward); traj.txt is camera-to-world"}
    (out / "cam.json").write_text(json.dumps(cam, indent=2) + "\n")
    (out / "synth.json").write_text(json.dumps(_config_record(cfg), indent=2) + "\n")
    log.info("synthetic sequence: %d frames %dx%d in %.1f s -> %s", cfg.frames, cfg.height, cfg.width,
             time.perf_counter() - t0, out)
    return out


def cache_root() -> Path:
    """``$LRSLAM_CACHE`` or ``~/.cache/lrslam``."""
    return Path(os.environ.get("LRSLAM_CACHE", Path.home() / ".cache" / "lrslam")).expanduser()


def default_sequence(cache_dir=None, cfg: SynthConfig | None = None) -> Path:
    """Folder of the default synthetic sequence, generated on first use and cached.

    The folder is ``<cache_dir or cache_root()>/synthetic_default`` (``synthetic_<seed>_<frames>_<H>x<W>_...``
    for a non-default ``cfg``). It is regenerated if its ``synth.json`` differs from the requested config or
    generator version. Generation writes to a temporary sibling folder and renames it, so concurrent
    callers never see a half-written sequence.
    """
    cfg = cfg or SynthConfig()
    root = Path(cache_dir).expanduser() if cache_dir is not None else cache_root()
    name = "synthetic_default" if cfg == SynthConfig() else "synthetic_" + _config_tag(cfg)
    target = root / name
    want = _config_record(cfg)
    if _holds(target, want):
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=root))
    try:
        generate(tmp, cfg)
        if _holds(target, want):
            # another process finished first: keep its copy, which readers may already hold open
            shutil.rmtree(tmp, ignore_errors=True)
            return target
        if target.exists():
            old = root / f".{name}.old.{os.getpid()}"
            try:
                target.rename(old)
                shutil.rmtree(old, ignore_errors=True)
            except OSError:
                pass
        try:
            tmp.rename(target)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not _holds(target, want):
                raise SlamInputError(f"{target}: cannot write the synthetic sequence into the cache") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def _holds(folder: Path, record: dict) -> bool:
    try:
        return json.loads((folder / "synth.json").read_text()) == record and (folder / "mesh.ply").exists()
    except (OSError, ValueError):
        return False


def _config_tag(cfg: SynthConfig) -> str:
    import hashlib

    blob = json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode()
    return f"{cfg.seed}_{cfg.frames}_{cfg.height}x{cfg.width}_" + hashlib.sha1(blob).hexdigest()[:8]
