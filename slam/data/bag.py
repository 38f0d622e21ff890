"""RGB-D recordings in ROS bags: a ROS 1 ``.bag`` file, or a ROS 2 bag folder (``metadata.yaml`` and its
``.db3`` (sqlite3) or ``.mcap`` files). Read through the ``rosbags`` package (the ``bags`` extra), no ROS install.

::

    colour        sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8) or sensor_msgs/CompressedImage (jpeg, png)
    depth         sensor_msgs/Image registered to the colour camera: 16UC1 (mono16), raw / depth_scale = metres
                  (default 1000: millimetres, as ROS's REP 118), or 32FC1 metres; 0 or NaN = no measurement
    camera        sensor_msgs/CameraInfo of the colour camera: K, and D as Brown-Conrady (plumb_bob)
    ground truth  optional: a TUM trajectory file (``groundtruth`` option), camera-to-world, OpenCV axes

Topics are found by type and name: colour is an Image or CompressedImage topic with ``rgb``/``color``/``colour``
in its name (not ``depth``; an uncompressed one preferred), depth an Image topic with ``depth`` in its name
(one aligned or registered to colour preferred), the camera the CameraInfo beside the colour topic. The two
reference layouts::

    TUM RGB-D's ROS 1 bags         /camera/rgb/image_color (rgb8), /camera/depth/image (32FC1),
                                   /camera/rgb/camera_info
    realsense-ros (ROS 2, with     /camera/camera/color/image_raw (rgb8),
    align_depth.enable:=true)      /camera/camera/aligned_depth_to_color/image_raw (16UC1 mm),
                                   /camera/camera/color/camera_info

The options ``color_topic``, ``depth_topic`` and ``camera_info_topic`` name them instead.

Opening a bag reads the colour and depth messages once, to index them by their header stamps (held: a few
numbers per message); a frame's images are read and decoded when the frame is asked for, so a bag of any size
opens in the time one pass over it takes and in little memory. Pairing follows the TUM loader
(:mod:`slam.data.tum`): every colour frame takes the nearest depth frame within ``max_dt`` and, with ground
truth, the ground truth at its stamp (interpolated), poses relative to the first kept frame by default.
Unlike TUM's reference loading no frame is dropped for being too close to the previous one (``min_dt`` 0):
a bag is a recording, not a benchmark whose reference skipped frames.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch

from slam.data.association import nearest, poses_at, spaced
from slam.data.bag_messages import (BAGS_REQUIREMENT, CAMERA_INFO, COLOR_ENCODINGS, DEPTH_ENCODINGS, IMAGE, Bag,
                                    camera_distortion, camera_intrinsics, decode_image, decode_rgb, image_size,
                                    index_topic)
from slam.data.bag_topics import find_topics
from slam.data.base import RGBDDataset
from slam.data.calibration import parse_depth_scale, parse_distortion, parse_intrinsics
from slam.data.tum_format import read_tum_poses
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["BagDataset", "BAGS_REQUIREMENT", "DEFAULT_DEPTH_SCALE", "looks_like"]

log = logging.getLogger(__name__)

#: 16-bit depth per metre when not given: millimetres (ROS REP 118; the RealSense and Kinect drivers)
DEFAULT_DEPTH_SCALE = 1000.0


def looks_like(root: Path) -> bool:
    """Whether ``root`` is a ROS bag: a ``.bag`` file (ROS 1), or a folder with ``metadata.yaml`` and ``.db3`` or
    ``.mcap`` files (ROS 2). Needs no ``rosbags``: a bag is recognised without the extra, which opening it asks for."""
    if root.is_file():
        return root.suffix == ".bag"
    return ((root / "metadata.yaml").is_file()
            and any(p.suffix in (".db3", ".mcap") for p in root.iterdir() if p.is_file()))


class BagDataset(RGBDDataset):
    """An RGB-D recording in a ROS bag (see module docstring).

    Args:
        path: a ROS 1 ``.bag`` file or a ROS 2 bag folder.
        color_topic, depth_topic, camera_info_topic: topic names instead of the ones found by type and name.
        groundtruth: a TUM trajectory file (``timestamp tx ty tz qx qy qz qw``, camera-to-world, OpenCV axes) in
            the stamps' clock; frames without ground truth within ``max_dt`` are dropped. None: poses unknown
            (SLAM runs, ATE is not computed).
        intrinsics: the colour camera instead of the CameraInfo's: an :class:`Intrinsics` or a mapping
            ``{fx, fy, cx, cy[, width, height]}`` (pixels; the size defaults to the images').
        distortion: ``(k1, k2, p1, p2[, k3])`` instead of the CameraInfo's D ([] for none).
        depth_scale: 16-bit depth value per metre (default 1000, millimetres); not for 32FC1 depth (metres).
        max_dt: seconds; largest colour-depth and colour-ground-truth gap accepted (the TUM loader's 0.08).
        min_dt: seconds; drop frames closer than this to the previous kept one (0: keep all).
        interpolate_gt: interpolate ground truth at the colour stamp (else nearest sample).
        relative_to_first: express poses relative to the first kept frame (as the TUM loader).
        crop_size, focal_px, crop_edge, crop_edge_raw, undistort, stride, max_frames: the common options (see
            :class:`RGBDDataset`).

    Attributes: ``color_topic``, ``depth_topic``, ``camera_info_topic`` (None with the ``intrinsics`` option and
    no CameraInfo), ``gt_file`` (Path or None), ``depth_encoding``.
    """

    def __init__(
        self,
        path,
        *,
        color_topic: str | None = None,
        depth_topic: str | None = None,
        camera_info_topic: str | None = None,
        groundtruth: str | Path | None = None,
        intrinsics: Intrinsics | dict | None = None,
        distortion=None,
        depth_scale: float | None = None,
        max_dt: float = 0.08,
        min_dt: float = 0.0,
        interpolate_gt: bool = True,
        relative_to_first: bool = True,
        crop_size: tuple[int, int] | None = None,
        crop_edge: int | None = None,
        crop_edge_raw: int | None = None,
        focal_px: float | None = None,
        undistort: bool = True,
        stride: int = 1,
        max_frames: int | None = None,
    ) -> None:
        self._open(Path(path))
        self.color_topic, self.depth_topic, self.camera_info_topic = find_topics(
            self._bag, color_topic, depth_topic, camera_info_topic)
        self._color_type = self._bag.topics[self.color_topic][0]
        self._pair(groundtruth, max_dt, min_dt, interpolate_gt, relative_to_first, stride, max_frames)
        size = self._check_first_frames(depth_scale)
        intr, dist = self._camera(size, intrinsics, distortion, undistort)
        self._set_camera(intr, dist if undistort else None, crop_size, crop_edge, crop_edge_raw, focal_px)
        log.info("%s: %d frames of %s and %s (%s), camera %s", self.root, len(self), self.color_topic,
                 self.depth_topic, self.depth_encoding, self.camera_info_topic or "from data.options.intrinsics")

    def _open(self, root: Path) -> None:
        """Open the bag at ``root`` (SlamInputError if it is none): sets ``root``, ``name``, ``source_files``."""
        if not looks_like(root):
            raise SlamInputError(f"{root}: not a ROS bag (a .bag file, or a folder with metadata.yaml and "
                                 ".db3/.mcap files)")
        self.root = root
        self.name = root.stem if root.is_file() else root.name
        # what a resume's fingerprint sizes up (slam.engine.setup): the bag's files, as a folder's are its images
        self.source_files = [root] if root.is_file() else sorted(
            p for p in root.iterdir() if p.suffix in (".db3", ".mcap"))
        self._bag = Bag(root)

    def _pair(self, groundtruth, max_dt: float, min_dt: float, interpolate_gt: bool, relative_to_first: bool,
              stride: int, max_frames: int | None) -> None:
        """Index the colour and depth topics and pair every colour frame with the nearest depth frame and the
        ground truth (module docstring); sets ``gt_file``, the kept frames' stamps and poses and their messages."""
        root, bag = self.root, self._bag
        color, depth = index_topic(bag, self.color_topic), index_topic(bag, self.depth_topic)
        rgb_ts, depth_ts = color.seconds(), depth.seconds()
        order = np.argsort(depth_ts, kind="stable")
        nd = order[nearest(depth_ts[order], rgb_ts)] if len(order) > 1 else np.zeros(len(rgb_ts), dtype=np.int64)
        keep = np.abs(depth_ts[nd] - rgb_ts) < max_dt
        self.gt_file = Path(groundtruth).expanduser() if groundtruth is not None else None
        if self.gt_file is not None:
            data = read_tum_poses(self.gt_file, what="ground-truth row")
            data = data[np.argsort(data[:, 0], kind="stable")]
            poses, has_gt = poses_at(data[:, 0], data[:, 1:8], rgb_ts, max_dt, interpolate_gt)
            keep &= has_gt
        else:
            poses = np.full((len(rgb_ts), 4, 4), np.nan)
        if min_dt > 0:
            keep = spaced(rgb_ts, keep, min_dt)
        if not keep.any():
            what = "a depth frame and ground truth" if self.gt_file is not None else "a depth frame"
            raise SlamInputError(
                f"{root}: no colour frame of {self.color_topic} ({len(rgb_ts)}, stamps {rgb_ts.min():.3f}.."
                f"{rgb_ts.max():.3f}) has {what} within {max_dt} s ({self.depth_topic}: {len(depth_ts)}, stamps "
                f"{depth_ts.min():.3f}..{depth_ts.max():.3f})")
        idx = np.flatnonzero(keep)
        poses = poses[idx]
        if relative_to_first and self.gt_file is not None:
            poses = np.linalg.inv(poses[0]) @ poses
        sel = idx[self._select(len(idx), poses, rgb_ts[idx], stride, max_frames, self.gt_file is None, self.gt_file)]
        self._color_ref = [(int(color.records[k]), int(color.ordinals[k])) for k in sel]
        self._depth_ref = [(int(depth.records[nd[k]]), int(depth.ordinals[nd[k]])) for k in sel]
        self._color_paths, self._depth_paths = [], []

    def _check_first_frames(self, depth_scale: float | None) -> tuple[int, int]:
        """Check the first frame's encodings and sizes (depth registered to colour); sets ``depth_encoding`` and
        ``depth_scale``; returns the images' size ``(H, W)``."""
        root, bag = self.root, self._bag
        first_c = bag.message(self.color_topic, *self._color_ref[0])
        first_d = bag.message(self.depth_topic, *self._depth_ref[0])
        self.depth_encoding = first_d.encoding
        if first_d.encoding not in DEPTH_ENCODINGS:
            raise SlamInputError(f"{root}: topic {self.depth_topic}: depth encoding {first_d.encoding!r} is not read "
                                 f"(expected one of {', '.join(DEPTH_ENCODINGS)})")
        if self._color_type == IMAGE and first_c.encoding not in COLOR_ENCODINGS:
            raise SlamInputError(f"{root}: topic {self.color_topic}: colour encoding {first_c.encoding!r} is not "
                                 f"read (expected one of {', '.join(COLOR_ENCODINGS)}, or a CompressedImage)")
        size = (int(first_d.height), int(first_d.width))
        csize = image_size(first_c, self._color_type, f"{root}: topic {self.color_topic}")
        if csize != size:
            raise SlamInputError(
                f"{root}: colour {self.color_topic} is {csize[0]}x{csize[1]} but depth {self.depth_topic} is "
                f"{size[0]}x{size[1]}: depth must be registered to the colour camera (realsense-ros: "
                "align_depth.enable:=true and its aligned_depth_to_color topic)")
        if first_d.encoding == "32FC1":
            if depth_scale is not None:
                raise SlamInputError(f"{root}: data.options.depth_scale is for 16-bit depth; {self.depth_topic} is "
                                     "32FC1, metres")
            scale = 1.0
        else:
            scale = (DEFAULT_DEPTH_SCALE if depth_scale is None
                     else parse_depth_scale(depth_scale, f"{root}: option 'depth_scale'"))
        self.depth_scale = float(scale)
        return size

    def _camera(self, size: tuple[int, int], intrinsics, distortion, undistort: bool):
        """(intrinsics, distortion) of the raw images ``size`` ``(H, W)``: the options, else the CameraInfo's."""
        bag, topic = self._bag, self.camera_info_topic
        info = None
        if topic is not None and (intrinsics is None or (distortion is None and undistort)):
            t, raw = next(bag.messages(topic), (None, None))
            info = bag.decode(raw, CAMERA_INFO, topic) if raw is not None else None
        if intrinsics is not None:
            intr = parse_intrinsics(intrinsics, f"{self.root}: option 'intrinsics'", image_size=size)
        elif info is None:
            raise SlamInputError(f"{self.root}: no sensor_msgs/CameraInfo of the colour camera (camera info topics: "
                                 f"{bag.describe((CAMERA_INFO,))}); name one with data.options.camera_info_topic or "
                                 "give data.options.intrinsics={fx, fy, cx, cy}")
        else:
            intr = camera_intrinsics(info, size, f"{self.root}: topic {topic}")
        if intr.height != size[0] or intr.width != size[1]:
            raise SlamInputError(f"{self.root}: option 'intrinsics' is for {intr.height}x{intr.width} images, the "
                                 f"images are {size[0]}x{size[1]}")
        if distortion is not None:
            dist = parse_distortion(distortion, f"{self.root}: option 'distortion'")
        elif info is not None and undistort:
            dist = camera_distortion(info, f"{bag.path}: topic {topic}")
        else:
            dist = None
        return intr, dist

    def _where(self, topic: str, i: int) -> str:
        return f"{self.root}: topic {topic}, frame {i} (stamp {self.timestamps[i]:.6f})"

    def _checked(self, img: np.ndarray, where: str) -> np.ndarray:
        h, w = self.raw_intrinsics.height, self.raw_intrinsics.width
        if tuple(img.shape[:2]) != (h, w):
            raise SlamInputError(f"{where}: image is {img.shape[0]}x{img.shape[1]}, expected {h}x{w} like the "
                                 "first frame")
        return img

    def raw_color(self, i: int) -> np.ndarray:
        """Colour of frame ``i`` as recorded: ``[H, W, 3]`` uint8 RGB."""
        msg = self._bag.message(self.color_topic, *self._color_ref[i])
        where = self._where(self.color_topic, i)
        return self._checked(decode_rgb(msg, self._color_type, where), where)

    def raw_depth(self, i: int) -> torch.Tensor:
        """Depth of frame ``i`` as recorded: ``[H, W]`` float32 metres, 0 = no measurement (NaN in 32FC1)."""
        msg = self._bag.message(self.depth_topic, *self._depth_ref[i])
        where = self._where(self.depth_topic, i)
        raw = self._checked(decode_image(msg, where, DEPTH_ENCODINGS)[..., 0], where)
        if raw.dtype == np.float32:
            return torch.from_numpy(np.where(np.isfinite(raw), raw, np.float32(0.0)))
        # the TUM folder's arithmetic (base.RGBDDataset.raw_depth): the same float32 metres from the same values
        return torch.from_numpy(raw.astype(np.float32)) / self.depth_scale
