"""The synthetic scenes in nerfstudio's data format: ``transforms.json``, PNG images and 16-bit depth.

For training nerfstudio methods on the project's procedural room (docs/nerf.md, "nerfstudio plugin")::

    from slam.data.synthetic import SynthConfig
    from slam.data.synthetic.nerfstudio_export import export_nerfstudio
    export_nerfstudio("data/room_ns", SynthConfig(frames=24, height=48, width=64, loop_frames=96))
    # ns-train tdfields-hybrid nerfstudio-data --data data/room_ns --center-method none --auto-scale-poses False
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from slam.data.synthetic.config import SynthConfig
from slam.data.synthetic.render import render_frame
from slam.data.synthetic.sequence import scene_and_path
from slam.errors import SlamInputError

#: depth PNG values per metre of z-depth (millimetres): nerfstudio multiplies them by its default
#: ``depth_unit_scale_factor`` (1e-3) and by the ``applied_scale`` below, giving depth in the saved coordinates
DEPTH_UNITS = 1000.0
# OpenCV camera axes (x right, y down, z forward) -> nerfstudio's OpenGL ones (x right, y up, z backward)
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def scene_normalisation(room_min: np.ndarray, room_max: np.ndarray, pad: float) -> tuple[np.ndarray, float]:
    """``(centre [3] metres, scale 1/m)`` that put the padded box ``room_min - pad .. room_max + pad`` inside
    ``[-1, 1]^3``, its longest axis exactly: saved coordinates are ``scale * (world - centre)``."""
    lo, hi = np.asarray(room_min, float) - pad, np.asarray(room_max, float) + pad
    return (lo + hi) / 2.0, 2.0 / float((hi - lo).max())


def export_nerfstudio(out_dir, cfg: SynthConfig | None = None, *, hold_out: int = 8, pad: float = 0.05) -> Path:
    """Render ``cfg``'s sequence into ``out_dir`` as a nerfstudio dataset; returns ``out_dir``.

    Files: ``images/frame_NNNNN.png`` (8-bit RGB), ``depths/frame_NNNNN.png`` (uint16, see :data:`DEPTH_UNITS`,
    0 = no surface), ``transforms.json`` and ``synth.json`` (the config). Colour is noise-free and depth exact
    (the sensor options of :class:`SynthConfig` are SLAM concerns and are refused here).

    Coordinates: the scene's box padded by ``pad`` metres is mapped into ``[-1, 1]^3`` (its longest axis exactly,
    :func:`scene_normalisation`), the map recorded as nerfstudio's ``applied_transform`` / ``applied_scale``, so
    nerfstudio's own ``[-1, 1]`` scene box fits the room when its parser leaves the poses alone:
    ``--center-method none --auto-scale-poses False`` (``orientation_override`` in the file sets orientation to
    ``none``; z stays up). Poses are camera-to-world in OpenGL axes. Principal points are shifted by half a pixel:
    nerfstudio's pixel ``i`` is centred at ``i + 0.5``, this project's at ``i``.

    Split: every ``hold_out``-th frame (0, 8, 16, ...) is the eval and test set, as in
    examples/fit_radiance_field.py, written into the file (``train_filenames`` / ``val_filenames`` /
    ``test_filenames``), so nerfstudio's ``--eval-mode`` does not change it.
    """
    import imageio.v3 as iio

    cfg = cfg or SynthConfig()
    cfg.validate()
    if cfg.depth_noise_sigma or cfg.color_noise_sigma or cfg.sensor_holes:
        raise SlamInputError("export_nerfstudio: the sensor options (noise, holes) are not exported; unset them")
    if hold_out < 2:
        raise SlamInputError(f"export_nerfstudio: hold_out must be >= 2, got {hold_out}")
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "depths").mkdir(exist_ok=True)
    scene, poses = scene_and_path(cfg)
    intr = cfg.intrinsics()
    centre, scale = scene_normalisation(scene.room_min, scene.room_max, pad)
    frames, names = [], []
    for i, pose in enumerate(poses):
        color, depth, _, _ = render_frame(scene, pose, intr, cfg.supersample)
        name = f"frame_{i:05d}.png"
        iio.imwrite(out / "images" / name, np.round(np.clip(color, 0, 1) * 255).astype(np.uint8))
        iio.imwrite(out / "depths" / name, np.round(np.clip(depth * DEPTH_UNITS, 0, 65535)).astype(np.uint16))
        c2w = np.array(pose, dtype=np.float64) @ _CV_TO_GL
        c2w[:3, 3] = scale * (c2w[:3, 3] - centre)
        frames.append({"file_path": f"images/{name}", "depth_file_path": f"depths/{name}",
                       "transform_matrix": c2w.tolist()})
        names.append(f"images/{name}")
    held = names[::hold_out]
    meta = {
        "camera_model": "OPENCV", "fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx + 0.5, "cy": intr.cy + 0.5,
        "w": intr.width, "h": intr.height, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "orientation_override": "none",
        "applied_transform": np.concatenate([np.eye(3), 0.0 - centre[:, None]], axis=1).tolist(),
        "applied_scale": scale,
        "train_filenames": [n for n in names if n not in held], "val_filenames": held, "test_filenames": held,
        "frames": frames,
    }
    (out / "transforms.json").write_text(json.dumps(meta, indent=1) + "\n")
    (out / "synth.json").write_text(json.dumps({"config": dataclasses.asdict(cfg), "hold_out": hold_out, "pad": pad,
                                                "centre": centre.tolist(), "scale": scale}, indent=2) + "\n")
    return out
