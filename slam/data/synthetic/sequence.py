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
from slam.data.synthetic.config import WALK_FRAMES, SynthConfig, walk_config
from slam.data.synthetic.mesh import scene_mesh
from slam.data.synthetic.render import render_frame, sensor_depth
from slam.data.synthetic.scene import build_scene
from slam.data.synthetic.walk import build_walk_scene, walk_path
from slam.errors import SlamInputError

log = logging.getLogger("slam.data.synthetic")

#: bump when the output of :func:`generate` changes for the same config, so caches regenerate
GENERATOR_VERSION = 3
#: the Replica depth PNG scale: metres = value / 6553.5 (65535 <-> 10 m, 0.15 mm steps)
DEPTH_SCALE = 6553.5


def _config_record(cfg: SynthConfig) -> dict:
    return {"generator_version": GENERATOR_VERSION, "config": _config_dict(cfg)}


def _config_dict(cfg: SynthConfig) -> dict:
    # the room's record as before the walk existed, so caches of the room stay valid
    d = dataclasses.asdict(cfg)
    if d["scene"] == "room":
        del d["scene"]
    return d


def scene_and_path(cfg: SynthConfig):
    """The config's scene (:class:`SynthScene`) and its ``[frames, 4, 4]`` camera-to-world poses."""
    if cfg.scene == "walk":
        return build_walk_scene(cfg.seed), walk_path(cfg)
    return build_scene(cfg.seed), camera_path(cfg)


def sensor_frame(scene, pose: np.ndarray, cfg: SynthConfig, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``i`` of the sequence as the sensor delivers it, before the PNGs' quantisation: colour ``[H, W, 3]``
    (float64, noisy, unclipped) and depth ``[H, W]`` (metres, 0 = hole) of the view from ``pose`` ``[4, 4]``
    (camera-to-world) with the config's sensor model and noises, drawn from the frame's own random stream."""
    color, depth, cos, _ = render_frame(scene, pose, cfg.intrinsics(), cfg.supersample)
    rng = np.random.default_rng([cfg.seed, 2, i])
    if cfg.sensor_holes:
        depth = sensor_depth(depth, cos, rng)
    if cfg.depth_noise_sigma > 0:
        valid = depth > 0
        depth = np.where(valid, depth + rng.normal(0.0, cfg.depth_noise_sigma, depth.shape), 0.0)
    if cfg.color_noise_sigma > 0:
        color = color + rng.normal(0.0, cfg.color_noise_sigma, color.shape)
    return color, depth


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
    scene, poses = scene_and_path(cfg)
    intr = cfg.intrinsics()
    for i, pose in enumerate(poses):
        color, depth = sensor_frame(scene, pose, cfg, i)
        col8 = np.round(np.clip(color, 0, 1) * 255).astype(np.uint8)
        # past the PNG's 10 m range (the walk without the sensor model) there is no reading
        depth = np.where(depth < 65535 / DEPTH_SCALE, np.maximum(depth, 0), 0)
        d16 = np.round(depth * DEPTH_SCALE).astype(np.uint16)
        # low zlib effort: 3x faster writes for ~10 % larger files
        iio.imwrite(out / "results" / f"frame{i:06d}.png", col8, compress_level=1)
        iio.imwrite(out / "results" / f"depth{i:06d}.png", d16, compress_level=1)
    np.savetxt(out / "traj.txt", poses.reshape(len(poses), 16), fmt="%.10f")
    mesh = scene_mesh(scene)
    mesh.export(out / "mesh.ply")
    name = "synthetic_walk" if cfg.scene == "walk" else "synthetic"
    cam = {**intr.as_dict(), "depth_scale": DEPTH_SCALE, "name": f"{name}_seed{cfg.seed}",
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


def walk_sequence(frames: int | None = None, cache_dir=None) -> Path:
    """Folder of the walk's first ``frames`` frames (default: the whole walk, :data:`WALK_FRAMES`), generated on
    first use into the cache like :func:`default_sequence` (an excerpt's frames equal the whole walk's)."""
    return default_sequence(cache_dir, walk_config(WALK_FRAMES if frames is None else frames))


def _holds(folder: Path, record: dict) -> bool:
    try:
        return json.loads((folder / "synth.json").read_text()) == record and (folder / "mesh.ply").exists()
    except (OSError, ValueError):
        return False


def _config_tag(cfg: SynthConfig) -> str:
    import hashlib

    blob = json.dumps(_config_dict(cfg), sort_keys=True).encode()
    prefix = "" if cfg.scene == "room" else cfg.scene + "_"
    return f"{prefix}{cfg.seed}_{cfg.frames}_{cfg.height}x{cfg.width}_" + hashlib.sha1(blob).hexdigest()[:8]
