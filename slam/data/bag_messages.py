"""The messages of a ROS bag (:mod:`slam.data.bag` loads the recording): the bag opened through ``rosbags``, a
topic's messages indexed by header stamp, and the decoding of ``sensor_msgs`` Image, CompressedImage and CameraInfo
into pixels and a camera."""

from __future__ import annotations

import logging
import threading
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["BAGS_REQUIREMENT", "CAMERA_INFO", "COLOR_ENCODINGS", "COMPRESSED", "DEPTH_ENCODINGS", "IMAGE", "Bag",
           "Stream", "camera_distortion", "camera_intrinsics", "decode_image", "decode_rgb", "image_size",
           "index_topic"]

log = logging.getLogger(__name__)

#: the package the ``bags`` extra installs (pyproject.toml)
BAGS_REQUIREMENT = "rosbags>=0.11"

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

#: encoding -> (numpy dtype, channels) of the Image encodings read
COLOR_ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
                   "mono8": (np.uint8, 1)}
DEPTH_ENCODINGS = {"16UC1": (np.uint16, 1), "mono16": (np.uint16, 1), "32FC1": (np.float32, 1)}
#: CameraInfo distortion models whose coefficients are Brown-Conrady in OpenCV's order (k1 k2 p1 p2 k3 [k4 k5 k6])
BROWN_CONRADY_MODELS = ("plumb_bob", "rational_polynomial", "")


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


class Bag:
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
class Stream:
    """One topic's messages as indexed at open: header stamps ``[N]`` (int ns, record order) and where each is
    (record time ns, position among the topic's messages of that record time)."""

    stamps: np.ndarray
    records: np.ndarray
    ordinals: np.ndarray

    def seconds(self) -> np.ndarray:
        # Python's int / int rounds correctly: a stamp written from "1305031233.693779" gives that float exactly
        return np.array([int(s) / 10**9 for s in self.stamps], dtype=np.float64)


def index_topic(bag: Bag, topic: str) -> Stream:
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
    return Stream(np.array(stamps, dtype=np.int64), np.array(records, dtype=np.int64),
                   np.array(ordinals, dtype=np.int64))


def decode_image(msg, where: str, encodings: dict) -> np.ndarray:
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


def decode_rgb(msg, msgtype: str, where: str) -> np.ndarray:
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
        img = decode_image(msg, where, COLOR_ENCODINGS)
        if msg.encoding.startswith("bgr"):
            img = img[..., 2::-1]
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[..., :3])


def image_size(msg, msgtype: str, where: str) -> tuple[int, int]:
    if msgtype == COMPRESSED:  # its size is in the compressed data only
        img = decode_rgb(msg, msgtype, where)
        return img.shape[0], img.shape[1]
    return int(msg.height), int(msg.width)


def _field(msg, name: str):
    """A CameraInfo field by its ROS 2 name (``k``, ``d``); ROS 1 spells the arrays in capitals."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def camera_intrinsics(msg, size: tuple[int, int], where: str) -> Intrinsics:
    """A CameraInfo's K as the camera of the raw images ``size`` ``(H, W)``; ``where`` (bag and topic) starts the
    errors: SlamInputError for an uncalibrated camera or one for images of another size."""
    k = [float(v) for v in _field(msg, "k")]
    if k[0] <= 0 or k[4] <= 0:
        raise SlamInputError(f"{where}: camera not calibrated (K = {k}); give "
                             "data.options.intrinsics={fx, fy, cx, cy}")
    info_size = (int(msg.height), int(msg.width))
    if info_size != (0, 0) and info_size != size:
        raise SlamInputError(f"{where} is for {info_size[0]}x{info_size[1]} images, the "
                             f"images are {size[0]}x{size[1]}")
    return Intrinsics(k[0], k[4], k[2], k[5], *size)


def camera_distortion(msg, where: str) -> tuple[float, ...] | None:
    """CameraInfo's D as Brown-Conrady ``(k1, k2, p1, p2, k3)`` (None: none); SlamInputError for a model
    :func:`slam.data.base.undistort_grid` does not apply."""
    model = str(msg.distortion_model)
    d = [float(v) for v in _field(msg, "d")]
    if not any(d):
        return None
    if model in BROWN_CONRADY_MODELS and not any(d[5:]):
        return tuple(d[:5])
    raise SlamInputError(f"{where}: distortion model {model!r} with coefficients {d} is not "
                         "undone here (Brown-Conrady k1 k2 p1 p2 k3 is); give data.options.distortion, or "
                         "data.options.undistort=false for images already rectified")
