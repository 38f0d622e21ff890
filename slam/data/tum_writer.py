"""Write an RGB-D recording in the TUM layout that :class:`slam.data.TUMDataset` reads.

::

    <out>/rgb/<t>.png          8-bit RGB, t = the colour timestamp in seconds ("%.6f")
    <out>/depth/<t>.png        16-bit depth, metres = value / depth_scale, 0 = no measurement
    <out>/rgb.txt, depth.txt   "timestamp file" per line, with TUM's comment header
    <out>/associations.txt     "rgb_ts rgb_file depth_ts depth_file": the pairs as recorded
    <out>/calibration.yaml     the colour camera (depth registered to it), distortion, depth scale
    <out>/groundtruth.txt      only when poses are given: "timestamp tx ty tz qx qy qz qw" camera-to-world

Used by ``examples/record_realsense.py``; any other camera works the same way::

    from slam.data.tum_writer import TUMWriter
    with TUMWriter("data/desk", intrinsics, depth_scale=1000.0) as rec:
        for t, rgb, depth in frames:           # rgb [H, W, 3] uint8, depth [H, W] uint16 raw or float metres
            rec.add(t, rgb, depth)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from slam.data.calibration import CALIBRATION_FILE, write_calibration
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["TUMWriter"]


class TUMWriter:
    """Append RGB-D frames to a TUM-layout folder; the lists and calibration are written by :meth:`close`.

    Args:
        root: output folder; created, and it must not hold a recording already (``overwrite=True`` replaces
            the lists; images of the same timestamps are overwritten).
        intrinsics: the camera of the colour images, to which depth is registered (aligned), on the images
            as written.
        distortion: ``(k1, k2, p1, p2[, k3])`` of the colour images, or None.
        depth_scale: depth PNG value per metre (RealSense: ``1 / depth_units``, usually 1000; TUM's Kinect: 5000).
        overwrite: allow writing into a folder that already holds a recording.
    """

    def __init__(self, root: str | Path, intrinsics: Intrinsics, *, distortion: Sequence[float] | None = None,
                 depth_scale: float = 1000.0, overwrite: bool = False) -> None:
        self.root = Path(root)
        if not depth_scale > 0:
            raise SlamInputError(f"{self.root}: depth scale must be positive, got {depth_scale}")
        if not overwrite and any((self.root / n).exists() for n in ("rgb.txt", "depth.txt", "associations.txt")):
            raise SlamInputError(f"{self.root}: already holds a recording (rgb.txt/depth.txt); pick a new folder")
        (self.root / "rgb").mkdir(parents=True, exist_ok=True)
        (self.root / "depth").mkdir(exist_ok=True)
        self.intrinsics = intrinsics
        self.distortion = tuple(float(d) for d in distortion) if distortion is not None else None
        self.depth_scale = float(depth_scale)
        self._rgb: list[tuple[float, str]] = []
        self._depth: list[tuple[float, str]] = []
        self._poses: list[tuple[float, np.ndarray]] = []
        self._closed = False

    def __len__(self) -> int:
        return len(self._rgb)

    def add(self, timestamp: float, color: np.ndarray, depth: np.ndarray, *, depth_timestamp: float | None = None,
            pose: np.ndarray | None = None) -> None:
        """Write one frame.

        Args:
            timestamp: seconds, increasing; names the colour image.
            color: ``[H, W, 3]`` uint8 RGB.
            depth: ``[H, W]`` uint16 raw values (written as they are) or float metres (times ``depth_scale``,
                rounded; NaN, inf, <= 0 and values past the 16-bit range become 0 = no measurement).
            depth_timestamp: seconds of the depth image (default ``timestamp``).
            pose: optional ``[4, 4]`` camera-to-world ground truth (OpenCV axes); all frames or none.
        """
        import imageio.v3 as iio

        if self._closed:
            raise RuntimeError("TUMWriter is closed")
        h, w = self.intrinsics.height, self.intrinsics.width
        color = np.asarray(color)
        depth = np.asarray(depth)
        if color.shape != (h, w, 3) or color.dtype != np.uint8:
            raise SlamInputError(f"colour frame must be [{h}, {w}, 3] uint8, got {list(color.shape)} {color.dtype}")
        if depth.shape != (h, w):
            raise SlamInputError(f"depth frame must be [{h}, {w}] (registered to colour), got {list(depth.shape)}")
        if depth.dtype != np.uint16:
            if not np.issubdtype(depth.dtype, np.floating):
                raise SlamInputError(f"depth frame must be uint16 raw or float metres, got {depth.dtype}")
            raw = np.nan_to_num(depth.astype(np.float64) * self.depth_scale, nan=0.0, posinf=0.0, neginf=0.0)
            raw = np.rint(raw)
            raw[(raw <= 0) | (raw > np.iinfo(np.uint16).max)] = 0
            depth = raw.astype(np.uint16)
        t = float(timestamp)
        td = t if depth_timestamp is None else float(depth_timestamp)
        if self._rgb and t <= self._rgb[-1][0]:
            raise SlamInputError(f"timestamps must increase: {t:.6f} after {self._rgb[-1][0]:.6f}")
        if (pose is None) != (not self._poses) and self._rgb:
            raise SlamInputError("give a pose with every frame or with none")
        rgb_name, depth_name = f"rgb/{t:.6f}.png", f"depth/{td:.6f}.png"
        iio.imwrite(self.root / rgb_name, np.ascontiguousarray(color))
        iio.imwrite(self.root / depth_name, np.ascontiguousarray(depth))
        self._rgb.append((t, rgb_name))
        self._depth.append((td, depth_name))
        if pose is not None:
            pose = np.asarray(pose, dtype=np.float64)
            if pose.shape != (4, 4) or not np.isfinite(pose).all():
                raise SlamInputError(f"pose of frame {len(self._rgb) - 1} must be a finite 4x4 matrix")
            self._poses.append((t, pose))

    def close(self) -> Path:
        """Write the lists, ``associations.txt``, ``calibration.yaml`` (and ``groundtruth.txt``); returns the folder."""
        if self._closed:
            return self.root
        self._closed = True
        name = self.root.name
        self._write("rgb.txt", ["# color images", f"# file: '{name}'", "# timestamp filename"]
                    + [f"{t:.6f} {f}" for t, f in self._rgb])
        self._write("depth.txt", ["# depth maps", f"# file: '{name}'", "# timestamp filename"]
                    + [f"{t:.6f} {f}" for t, f in self._depth])
        self._write("associations.txt", [f"{t:.6f} {f} {td:.6f} {fd}"
                                         for (t, f), (td, fd) in zip(self._rgb, self._depth)])
        if self._poses:
            from slam.core.geometry import poses_to_tum

            rows = poses_to_tum(np.stack([p for _, p in self._poses]))
            self._write("groundtruth.txt", ["# ground truth trajectory", f"# file: '{name}'",
                                            "# timestamp tx ty tz qx qy qz qw"]
                        + [f"{t:.6f} " + " ".join(f"{v:.7f}" for v in r) for (t, _), r in zip(self._poses, rows)])
        write_calibration(self.root / CALIBRATION_FILE, self.intrinsics, self.distortion, self.depth_scale)
        return self.root

    def _write(self, name: str, lines: list[str]) -> None:
        tmp = self.root / f".{name}.tmp"
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, self.root / name)  # a reader never sees half a list

    def __enter__(self) -> "TUMWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # keep what was recorded when the recording is interrupted (Ctrl-C) or fails midway
        if self._rgb:
            self.close()
