"""Replica in the NICE-SLAM pre-rendered layout (also the layout of our synthetic scene).

::

    <scene>/results/frame000000.jpg   (or .png)   colour
    <scene>/results/depth000000.png               uint16 depth, metres = value / 6553.5
    <scene>/traj.txt                              one line per frame: 16 floats, row-major 4x4 camera-to-world
    <scene>/cam.json                              optional (ours): intrinsics and depth scale
    <scene>/mesh.ply or <scene>/../<scene>_mesh.ply   optional ground-truth mesh

NICE-SLAM's traj.txt is camera-to-world with OpenCV camera axes, which is our convention, so poses are used
as stored. Replica has no timestamps; frame ``i`` gets ``i / fps`` seconds.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from slam.data.base import RGBDDataset
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["ReplicaDataset", "REPLICA_INTRINSICS", "REPLICA_DEPTH_SCALE", "looks_like", "read_replica_traj"]

#: NICE-SLAM's camera for every Replica scene.
REPLICA_INTRINSICS = Intrinsics(fx=600.0, fy=600.0, cx=599.5, cy=339.5, height=680, width=1200)
REPLICA_DEPTH_SCALE = 6553.5


def _frame_number(p: Path) -> int:
    m = re.search(r"(\d+)$", p.stem)
    return int(m.group(1)) if m else -1


def read_replica_traj(path: Path) -> np.ndarray:
    """Read ``traj.txt`` (16 floats per line) as ``[N, 4, 4]`` float64; SlamInputError on bad lines."""
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    except FileNotFoundError:
        raise SlamInputError(f"{path}: trajectory file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SlamInputError(f"{path}: cannot read ({exc})") from None
    poses = np.empty((len(lines), 4, 4))
    for k, ln in enumerate(lines):
        parts = ln.split()
        if len(parts) != 16:
            raise SlamInputError(f"{path}:{k + 1}: expected 16 numbers (row-major 4x4), got {len(parts)}")
        try:
            poses[k] = np.array([float(v) for v in parts]).reshape(4, 4)
        except ValueError as exc:
            raise SlamInputError(f"{path}:{k + 1}: non-numeric value ({exc})") from None
    return poses


def looks_like(root: Path) -> bool:
    """Whether ``root`` is laid out as a Replica scene (``results/`` and ``traj.txt``; the synthetic room too)."""
    return (root / "results").is_dir() and (root / "traj.txt").exists()


def _frame_files(results: Path) -> tuple[list[Path], list[Path]]:
    """The colour (``frame*``) and depth (``depth*.png``) images of ``results/``, paired by frame number."""
    colors = sorted(
        [p for p in results.glob("frame*") if p.suffix.lower() in (".jpg", ".jpeg", ".png")], key=_frame_number
    )
    depths = sorted(results.glob("depth*.png"), key=_frame_number)
    if len(colors) != len(depths):
        raise SlamInputError(f"{results}: {len(colors)} colour images (frame*) but {len(depths)} depth images (depth*)")
    for c, d in zip(colors, depths):
        if _frame_number(c) != _frame_number(d):
            # equal counts with different numbering would pair the wrong images silently
            raise SlamInputError(f"{results}: {c.name} is paired with {d.name}; frame numbers must match")
    return colors, depths


def _camera_file(cam_path: Path, intrinsics: Intrinsics | None) -> tuple[dict, Intrinsics]:
    """``(cam.json's contents or {}, the camera)``: ``intrinsics`` if given, else cam.json's, else NICE-SLAM's."""
    cam = {}
    if cam_path.exists():
        try:
            cam = json.loads(cam_path.read_text())
            if intrinsics is None:
                intrinsics = Intrinsics(
                    float(cam["fx"]), float(cam["fy"]), float(cam["cx"]), float(cam["cy"]),
                    int(cam["height"]), int(cam["width"]),
                )
        except (ValueError, KeyError, TypeError) as exc:
            raise SlamInputError(f"{cam_path}: bad camera file ({type(exc).__name__}: {exc})") from None
    return cam, REPLICA_INTRINSICS if intrinsics is None else intrinsics


def _find_mesh(root: Path) -> Path | None:
    """The scene's ground-truth mesh: ``<scene>/mesh.ply`` or ``<scene>/../<scene>_mesh.ply``, else None."""
    for cand in (root / "mesh.ply", root.parent / f"{root.name}_mesh.ply"):
        if cand.exists():
            return cand
    return None


class ReplicaDataset(RGBDDataset):
    """Replica / synthetic sequence in the NICE-SLAM layout (see module docstring).

    Args:
        path: the scene folder (holds ``results/`` and ``traj.txt``).
        intrinsics: camera override; default: ``cam.json`` if present, else :data:`REPLICA_INTRINSICS`.
        depth_scale: override; default ``cam.json``'s ``depth_scale`` or 6553.5.
        fps: frame rate used to invent timestamps (``i / fps`` seconds).
        gt_mesh: ground-truth mesh path override.
        **options: crop_size, crop_edge, stride, max_frames (see :class:`RGBDDataset`).
    """

    def __init__(
        self,
        path,
        *,
        intrinsics: Intrinsics | None = None,
        depth_scale: float | None = None,
        fps: float = 30.0,
        gt_mesh=None,
        **options,
    ) -> None:
        root = Path(path)
        results = root / "results"
        if not results.is_dir():
            raise SlamInputError(f"{root}: not a Replica-layout folder (no results/ directory)")
        cam, intrinsics = _camera_file(root / "cam.json", intrinsics)
        colors, depths = _frame_files(results)
        if depth_scale is None:
            depth_scale = float(cam.get("depth_scale", REPLICA_DEPTH_SCALE))
        poses = read_replica_traj(root / "traj.txt")
        if len(poses) != len(colors):
            raise SlamInputError(f"{root / 'traj.txt'}: {len(poses)} poses but {len(colors)} frames in {results}")
        self.name = str(cam.get("name", root.name))
        self.gt_mesh_path = Path(gt_mesh) if gt_mesh is not None else _find_mesh(root)
        self._setup(
            root=root,
            color_paths=colors,
            depth_paths=depths,
            poses=poses,
            timestamps=[i / fps for i in range(len(colors))],
            intrinsics=intrinsics,
            depth_scale=depth_scale,
            pose_source=root / "traj.txt",
            **options,
        )
