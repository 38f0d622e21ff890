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
import threading
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from slam.data.association import nearest, poses_at, spaced
from slam.data.base import RGBDDataset
from slam.data.calibration import parse_depth_scale, parse_distortion, parse_intrinsics
from slam.data.tum_format import read_tum_poses
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["BagDataset", "BAGS_REQUIREMENT", "DEFAULT_DEPTH_SCALE", "looks_like"]

log = logging.getLogger(__name__)

#: the package the ``bags`` extra installs (pyproject.toml)
BAGS_REQUIREMENT = "rosbags>=0.11"
#: 16-bit depth per metre when not given: millimetres (ROS REP 118; the RealSense and Kinect drivers)
DEFAULT_DEPTH_SCALE = 1000.0

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

#: encoding -> (numpy dtype, channels) of the Image encodings read
COLOR_ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
                   "mono8": (np.uint8, 1)}
DEPTH_ENCODINGS = {"16UC1": (np.uint16, 1), "mono16": (np.uint16, 1), "32FC1": (np.float32, 1)}
#: CameraInfo distortion models whose coefficients are Brown-Conrady in OpenCV's order (k1 k2 p1 p2 k3 [k4 k5 k6])
BROWN_CONRADY_MODELS = ("plumb_bob", "rational_polynomial", "")


def looks_like(root: Path) -> bool:
    """Whether ``root`` is a ROS bag: a ``.bag`` file (ROS 1), or a folder with ``metadata.yaml`` and ``.db3`` or
    ``.mcap`` files (ROS 2). Needs no ``rosbags``: a bag is recognised without the extra, which opening it asks for."""
    if root.is_file():
        return root.suffix == ".bag"
    return ((root / "metadata.yaml").is_file()
            and any(p.suffix in (".db3", ".mcap") for p in root.iterdir() if p.is_file()))


def _readers():
    """``(rosbag1 Reader, rosbag2 Reader, get_typestore, Stores)``; SlamInputError with the install command
    without the ``bags`` extra."""
    try:
        from rosbags.rosbag1 import Reader as Reader1
        from rosbags.rosbag2 import Reader as Reader2
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        from slam._deps import install_command

        raise SlamInputError(f"reading ROS bags needs rosbags, which is not installed; install the bags extra: "
                             f"{install_command('bags')} (or: python3 -m pip install \"{BAGS_REQUIREMENT}\")") from None
    return Reader1, Reader2, get_typestore, Stores


class _Bag:
    """An open bag: its topics, messages by topic and record time, and their deserialisation (ROS 1 or CDR with
    the stock message definitions: Image, CompressedImage and CameraInfo are the same in every distribution).
    One lock serialises the readers: frames are read on a background thread as well as the loop's."""

    def __init__(self, path: Path):
        Reader1, Reader2, get_typestore, Stores = _readers()
        self.path = path
        self.ros1 = path.is_file()
        self.what = "ROS 1 bag" if self.ros1 else "ROS 2 bag"
        self.lock = threading.Lock()
        try:
            self.reader = Reader1(path) if self.ros1 else Reader2(path)
            self.reader.open()
        except Exception as exc:  # rosbags raises its own, the storage's (apsw, mcap) and struct errors
            raise SlamInputError(f"{path}: cannot open the {self.what}, truncated or corrupt? "
                                 f"({type(exc).__name__}: {exc})") from None
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        self.topics: dict[str, tuple[str, int]] = {}  # name -> (message type, messages)
        self.connections: dict[str, list] = {}
        for c in self.reader.connections:
            msgtype, count = self.topics.get(c.topic, (c.msgtype, 0))
            self.topics[c.topic] = (msgtype, count + c.msgcount)
            self.connections.setdefault(c.topic, []).append(c)

    def describe(self, types: tuple[str, ...] | None = None) -> str:
        """``name (type, N messages), ...`` of the topics (of ``types``) for error messages."""
        items = [f"{n} ({t}, {c} messages)" for n, (t, c) in sorted(self.topics.items()) if types is None or t in types]
        return ", ".join(items) if items else "none"

    def messages(self, topic: str, start: int | None = None, stop: int | None = None):
        """``(record time ns, raw bytes)`` of ``topic``'s messages in record order, in ``[start, stop)`` if given."""
        try:
            for _, t, raw in self.reader.messages(connections=self.connections[topic], start=start, stop=stop):
                yield t, raw
        except SlamInputError:
            raise
        except Exception as exc:  # a damaged chunk or record surfaces only when read
            raise SlamInputError(f"{self.path}: topic {topic}: cannot read its messages, truncated or corrupt? "
                                 f"({type(exc).__name__}: {exc})") from None

    def decode(self, raw: bytes, msgtype: str, topic: str):
        try:
            if self.ros1:
                return self.typestore.deserialize_ros1(raw, msgtype)
            return self.typestore.deserialize_cdr(raw, msgtype)
        except Exception as exc:  # rosbags' serde raises several types for a message cut short
            raise SlamInputError(f"{self.path}: topic {topic}: a {msgtype} message cannot be decoded "
                                 f"({type(exc).__name__}: {exc})") from None

    def message(self, topic: str, record_ns: int, ordinal: int):
        """The ``ordinal``-th message of ``topic`` recorded at ``record_ns``, deserialised."""
        # closed at once, not when collected: the sqlite3 storage holds a cursor open until then
        with self.lock, closing(self.messages(topic, record_ns, record_ns + 1)) as found:
            for n, (_, raw) in enumerate(found):
                if n == ordinal:
                    return self.decode(raw, self.topics[topic][0], topic)
        raise SlamInputError(f"{self.path}: topic {topic}: the message recorded at {record_ns} ns is gone")


@dataclass
class _Stream:
    """One topic's messages as indexed at open: header stamps ``[N]`` (int ns, record order) and where each is
    (record time ns, position among the topic's messages of that record time)."""

    stamps: np.ndarray
    records: np.ndarray
    ordinals: np.ndarray

    def seconds(self) -> np.ndarray:
        # Python's int / int rounds correctly: a stamp written from "1305031233.693779" gives that float exactly
        return np.array([int(s) / 10**9 for s in self.stamps], dtype=np.float64)


def _index(bag: _Bag, topic: str) -> _Stream:
    """Read every message of ``topic`` once for its header stamp (all zero: a driver that did not stamp; the record
    times then)."""
    msgtype = bag.topics[topic][0]
    stamps, records, ordinals = [], [], []
    last, n = None, 0
    for t, raw in bag.messages(topic):
        stamp = bag.decode(raw, msgtype, topic).header.stamp
        n = n + 1 if t == last else 0
        last = t
        stamps.append(stamp.sec * 10**9 + stamp.nanosec)
        records.append(t)
        ordinals.append(n)
    if not stamps:
        raise SlamInputError(f"{bag.path}: topic {topic} has no messages")
    if not any(stamps):
        log.warning("%s: topic %s has no header stamps; pairing by record time", bag.path, topic)
        stamps = list(records)
    return _Stream(np.array(stamps, dtype=np.int64), np.array(records, dtype=np.int64),
                   np.array(ordinals, dtype=np.int64))


def _image(msg, where: str, encodings: dict) -> np.ndarray:
    """An Image message's pixels as ``[H, W, C]`` of the encoding's dtype (native byte order, rows unpadded);
    ``where`` (bag and topic) starts the errors."""
    enc = msg.encoding
    if enc not in encodings:
        raise SlamInputError(f"{where}: image encoding {enc!r} is not read (expected one of {', '.join(encodings)})")
    dtype, channels = encodings[enc]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < row or len(data) < step * h:
        raise SlamInputError(f"{where}: a {h}x{w} {enc} image holds {len(data)} bytes with rows of {step}; "
                             f"expected at least {h} rows of {row}")
    rows = np.ascontiguousarray(data[: step * h].reshape(h, step)[:, :row])
    return rows.view(dtype).reshape(h, w, channels).astype(dtype.newbyteorder("="))


def _rgb(msg, msgtype: str, where: str) -> np.ndarray:
    """A colour message as ``[H, W, 3]`` uint8 RGB."""
    if msgtype == COMPRESSED:
        import imageio.v3 as iio

        try:
            img = iio.imread(np.asarray(msg.data, dtype=np.uint8).tobytes(), plugin="pillow")
        except Exception as exc:  # imageio raises many types for corrupt data
            raise SlamInputError(f"{where}: cannot decode a {msg.format!r} compressed image "
                                 f"({type(exc).__name__}: {exc})") from None
        if img.dtype != np.uint8:
            raise SlamInputError(f"{where}: expected 8-bit compressed colour, got {img.dtype} ({msg.format!r})")
        img = img[..., None] if img.ndim == 2 else img
    else:
        img = _image(msg, where, COLOR_ENCODINGS)
        if msg.encoding.startswith("bgr"):
            img = img[..., 2::-1]
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[..., :3])


def _size_of(msg, msgtype: str, where: str) -> tuple[int, int]:
    if msgtype == COMPRESSED:  # its size is in the compressed data only
        img = _rgb(msg, msgtype, where)
        return img.shape[0], img.shape[1]
    return int(msg.height), int(msg.width)


def _field(msg, name: str):
    """A CameraInfo field by its ROS 2 name (``k``, ``d``); ROS 1 spells the arrays in capitals."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def _given(bag: _Bag, option: str, given: str, types: tuple[str, ...]) -> str:
    """The topic an option names, checked to exist with one of ``types``."""
    if given not in bag.topics:
        raise SlamInputError(f"{bag.path}: data.options.{option} = {given!r} is not a topic of the bag; its "
                             f"{' / '.join(types)} topics: {bag.describe(types)}")
    if bag.topics[given][0] not in types:
        raise SlamInputError(f"{bag.path}: data.options.{option} = {given!r} is a {bag.topics[given][0]} topic, "
                             f"expected {' or '.join(types)}")
    return given


def _pick(bag: _Bag, option: str, given: str | None, types: tuple[str, ...], what: str, candidates, rank) -> str:
    """The topic ``given`` (checked), else the best-ranked of ``candidates`` (lowest ``rank``); SlamInputError
    naming the topics when there is none or several tie."""
    if given is not None:
        return _given(bag, option, given, types)
    found = sorted(candidates, key=rank)
    if not found:
        raise SlamInputError(f"{bag.path}: no {what} topic; the bag has: {bag.describe()} "
                             f"(name one with data.options.{option})")
    tied = [t for t in found if rank(t) == rank(found[0])]
    if len(tied) > 1:
        raise SlamInputError(f"{bag.path}: several {what} topics ({', '.join(tied)}); name one with "
                             f"data.options.{option}")
    return found[0]


def _topics(bag: _Bag, color_topic, depth_topic, info_topic) -> tuple[str, str, str | None]:
    """The colour, depth and camera-info topics (module docstring); the last None when the bag has none."""
    if not any(c for _, c in bag.topics.values()):
        raise SlamInputError(f"{bag.path}: the {bag.what} holds no messages (topics: {bag.describe()})")
    live = {n: t for n, (t, c) in bag.topics.items() if c > 0}
    low = {n: n.lower() for n in live}
    color = _pick(
        bag, "color_topic", color_topic, (IMAGE, COMPRESSED), "colour",
        [n for n, t in live.items() if t in (IMAGE, COMPRESSED) and "depth" not in low[n]
         and any(w in low[n] for w in ("rgb", "color", "colour"))],
        lambda n: (live[n] == COMPRESSED, "mono" in low[n]))
    depth = _pick(
        bag, "depth_topic", depth_topic, (IMAGE,), "depth (sensor_msgs/Image with 'depth' in its name)",
        [n for n, t in live.items() if t == IMAGE and "depth" in low[n]],
        lambda n: not any(w in low[n] for w in ("aligned", "registered")))
    if info_topic is not None:
        return color, depth, _given(bag, "camera_info_topic", info_topic, (CAMERA_INFO,))
    infos = [n for n, t in live.items() if t == CAMERA_INFO]
    parts = color.split("/")
    for k in range(len(parts) - 1, 0, -1):  # the colour topic's own namespace first, then its parents'
        name = "/".join(parts[:k]) + "/camera_info"
        if name in infos:
            return color, depth, name
    colour_infos = [n for n in infos if "depth" not in low[n] and any(w in low[n] for w in ("rgb", "color", "colour"))]
    return color, depth, colour_infos[0] if len(colour_infos) == 1 else None


def _distortion(bag: _Bag, msg, topic: str) -> tuple[float, ...] | None:
    """CameraInfo's D as Brown-Conrady ``(k1, k2, p1, p2, k3)`` (None: none); SlamInputError for a model
    :func:`slam.data.base.undistort_grid` does not apply."""
    model = str(msg.distortion_model)
    d = [float(v) for v in _field(msg, "d")]
    if not any(d):
        return None
    if model in BROWN_CONRADY_MODELS and not any(d[5:]):
        return tuple(d[:5])
    raise SlamInputError(f"{bag.path}: topic {topic}: distortion model {model!r} with coefficients {d} is not "
                         "undone here (Brown-Conrady k1 k2 p1 p2 k3 is); give data.options.distortion, or "
                         "data.options.undistort=false for images already rectified")


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
        crop_size, crop_edge, undistort, stride, max_frames: the common options (see :class:`RGBDDataset`).

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
        crop_edge: int = 0,
        undistort: bool = True,
        stride: int = 1,
        max_frames: int | None = None,
    ) -> None:
        root = Path(path)
        if not looks_like(root):
            raise SlamInputError(f"{root}: not a ROS bag (a .bag file, or a folder with metadata.yaml and "
                                 ".db3/.mcap files)")
        self.root = root
        self.name = root.stem if root.is_file() else root.name
        # what a resume's fingerprint sizes up (slam.engine.setup): the bag's files, as a folder's are its images
        self.source_files = [root] if root.is_file() else sorted(
            p for p in root.iterdir() if p.suffix in (".db3", ".mcap"))
        self._bag = bag = _Bag(root)
        self.color_topic, self.depth_topic, self.camera_info_topic = _topics(bag, color_topic, depth_topic,
                                                                             camera_info_topic)
        self._color_type = bag.topics[self.color_topic][0]
        color, depth = _index(bag, self.color_topic), _index(bag, self.depth_topic)

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
        csize = _size_of(first_c, self._color_type, f"{root}: topic {self.color_topic}")
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
        intr, dist = self._camera(size, intrinsics, distortion, undistort)
        self._set_camera(intr, dist if undistort else None, crop_size, crop_edge)
        log.info("%s: %d frames of %s and %s (%s), camera %s", root, len(self), self.color_topic, self.depth_topic,
                 self.depth_encoding, self.camera_info_topic or "from data.options.intrinsics")

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
            k = [float(v) for v in _field(info, "k")]
            if k[0] <= 0 or k[4] <= 0:
                raise SlamInputError(f"{self.root}: topic {topic}: camera not calibrated (K = {k}); give "
                                     "data.options.intrinsics={fx, fy, cx, cy}")
            info_size = (int(info.height), int(info.width))
            if info_size != (0, 0) and info_size != size:
                raise SlamInputError(f"{self.root}: topic {topic} is for {info_size[0]}x{info_size[1]} images, the "
                                     f"images are {size[0]}x{size[1]}")
            intr = Intrinsics(k[0], k[4], k[2], k[5], *size)
        if intr.height != size[0] or intr.width != size[1]:
            raise SlamInputError(f"{self.root}: option 'intrinsics' is for {intr.height}x{intr.width} images, the "
                                 f"images are {size[0]}x{size[1]}")
        if distortion is not None:
            dist = parse_distortion(distortion, f"{self.root}: option 'distortion'")
        elif info is not None and undistort:
            dist = _distortion(bag, info, topic)
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
        return self._checked(_rgb(msg, self._color_type, where), where)

    def raw_depth(self, i: int) -> torch.Tensor:
        """Depth of frame ``i`` as recorded: ``[H, W]`` float32 metres, 0 = no measurement (NaN in 32FC1)."""
        msg = self._bag.message(self.depth_topic, *self._depth_ref[i])
        where = self._where(self.depth_topic, i)
        raw = self._checked(_image(msg, where, DEPTH_ENCODINGS)[..., 0], where)
        if raw.dtype == np.float32:
            return torch.from_numpy(np.where(np.isfinite(raw), raw, np.float32(0.0)))
        # the TUM folder's arithmetic (base.RGBDDataset.raw_depth): the same float32 metres from the same values
        return torch.from_numpy(raw.astype(np.float32)) / self.depth_scale
