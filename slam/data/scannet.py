"""ScanNet sequences as extracted by the official SensReader.

::

    <scene>/color/<i>.jpg       1296x968 colour (resized here to the depth size)
    <scene>/depth/<i>.png       640x480 uint16, metres = value / 1000
    <scene>/pose/<i>.txt        4x4 camera-to-world (OpenCV camera axes); '-inf' rows mark a lost pose
    <scene>/intrinsic/intrinsic_depth.txt   optional 4x4 depth camera matrix

Files are paired by integer file name. A frame whose pose contains inf/NaN keeps an all-NaN pose
(``Frame.has_valid_pose`` is False); ATE skips such frames. NICE-SLAM's ``frames/`` sub-level is accepted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slam.data.base import RGBDDataset
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["ScanNetDataset", "SCANNET_INTRINSICS", "SCANNET_DEPTH_SCALE", "looks_like"]

#: the reference configs' depth camera, used for every scene when no intrinsic/ folder exists
SCANNET_INTRINSICS = Intrinsics(577.590698, 578.729797, 318.905426, 242.683609, 480, 640)
SCANNET_DEPTH_SCALE = 1000.0


def looks_like(root: Path) -> bool:
    """Whether ``root`` is laid out as a ScanNet scene (``color/`` and ``depth/`` folders)."""
    return (root / "color").is_dir() and (root / "depth").is_dir()


def _by_number(folder: Path, suffixes: tuple[str, ...]) -> dict[int, Path]:
    out = {}
    for p in folder.iterdir():
        if p.suffix.lower() in suffixes and p.stem.isdigit():
            out[int(p.stem)] = p
    return out


def _read_matrix(path: Path) -> np.ndarray:
    try:
        rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
        m = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SlamInputError(f"{path}: cannot read a 4x4 matrix ({exc})") from None
    if m.shape != (4, 4):
        raise SlamInputError(f"{path}: expected a 4x4 matrix, got shape {m.shape}")
    return m


class ScanNetDataset(RGBDDataset):
    """A ScanNet scene (see module docstring).

    Args:
        path: folder holding color/, depth/, pose/ (or its ``frames/`` sub-folder).
        intrinsics: override; default ``intrinsic/intrinsic_depth.txt`` or :data:`SCANNET_INTRINSICS`.
        depth_scale: raw / metres (1000).
        **options: crop_size, crop_edge (reference: 10), stride, max_frames (see :class:`RGBDDataset`).
    """

    def __init__(self, path, *, intrinsics: Intrinsics | None = None, depth_scale: float = SCANNET_DEPTH_SCALE,
                 **options) -> None:
        root = Path(path)
        if not (root / "color").is_dir() and (root / "frames" / "color").is_dir():
            root = root / "frames"
        for sub in ("color", "depth", "pose"):
            if not (root / sub).is_dir():
                raise SlamInputError(f"{root}: not a ScanNet folder (no {sub}/ directory)")
        self.name = Path(path).name
        colors = _by_number(root / "color", (".jpg", ".jpeg", ".png"))
        depths = _by_number(root / "depth", (".png",))
        poses = _by_number(root / "pose", (".txt",))
        if len(colors) != len(depths):
            raise SlamInputError(f"{root}: {len(colors)} colour images but {len(depths)} depth images")
        missing = sorted(set(colors) ^ set(depths))
        if missing:
            raise SlamInputError(f"{root}: frame {missing[0]} has colour or depth but not both")
        no_pose = sorted(set(colors) - set(poses))
        if no_pose:
            raise SlamInputError(f"{root / 'pose'}: no pose file for frame {no_pose[0]}")
        ids = sorted(colors)
        mats = np.stack([_read_matrix(poses[i]) for i in ids]) if ids else np.zeros((0, 4, 4))
        bad = ~np.isfinite(mats).all(axis=(1, 2))
        mats[bad] = np.nan  # one marker for "no ground truth", whatever the file held
        depth_hw = None
        if ids:
            import imageio.v3 as iio

            try:
                depth_hw = tuple(iio.improps(depths[ids[0]]).shape[:2])
            except Exception as exc:
                raise SlamInputError(f"{depths[ids[0]]}: cannot read depth image ({exc})") from None
        if intrinsics is None:
            kfile = root / "intrinsic" / "intrinsic_depth.txt"
            if not kfile.exists():
                kfile = Path(path) / "intrinsic" / "intrinsic_depth.txt"
            if kfile.exists():
                # SensReader's matrix is for the depth images as stored
                k = _read_matrix(kfile)
                h, w = depth_hw or (480, 640)
                intrinsics = Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], h, w)
            else:
                intrinsics = SCANNET_INTRINSICS
                if depth_hw is not None and depth_hw != (intrinsics.height, intrinsics.width):
                    intrinsics = intrinsics.resized(*depth_hw)
        self._setup(
            root=root,
            color_paths=[colors[i] for i in ids],
            depth_paths=[depths[i] for i in ids],
            poses=mats,
            timestamps=[i / 30.0 for i in ids],
            intrinsics=intrinsics,
            depth_scale=depth_scale,
            allow_invalid_poses=True,
            **options,
        )
