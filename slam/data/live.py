"""A running camera as the data of a SLAM run (``lrslam live``): :class:`LiveFeed` receives frames on a thread as
the camera delivers them and serves them as a dataset whose length grows; the SLAM loop
(:mod:`slam.engine.system`) takes the newest frame each time it is free and drops the ones it missed, as
``--realtime`` does with a recorded folder.

A camera is any object with ``open() -> (Intrinsics, distortion or None, depth_scale)``, ``read() -> (t, rgb,
depth) or None`` (``t`` seconds, ``rgb [H, W, 3]`` uint8, ``depth [H, W]`` uint16 raw, metres = value /
depth_scale, 0 = none; None: the stream has ended) and ``close()``. :class:`RealSense` is one, over
``pyrealsense2`` (the ``realsense`` extra), with depth aligned to colour on the host.

Every frame received can be written as it arrives to a TUM-layout folder (:class:`slam.data.tum_writer.TUMWriter`),
so a live run can be redone offline with ``lrslam run --config tum --data FOLDER``. Frames are kept in memory only
while they may still be taken (the newest few) or once they were (their depth culls the mesh afterwards).
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np
import torch

from slam.data.types import Frame, Intrinsics
from slam.errors import SlamInputError

log = logging.getLogger(__name__)

__all__ = ["LiveFeed", "RealSense"]

#: frames kept that the loop has not taken (older ones can only be dropped: the loop takes the newest)
KEEP_UNTAKEN = 4


class LiveFeed:
    """Frames of ``camera`` as they arrive (a dataset for :class:`slam.engine.system.SLAM`).

    Args:
        camera: see the module's text; opened here, read on a thread of its own, closed by :meth:`close`.
        record: a folder to write every frame to in the TUM layout as it arrives (None: nothing written).
        max_frames: stop after this many frames (None: until :meth:`close` or the camera's end).

    Attributes: ``intrinsics``, ``distortion``, ``depth_scale`` (the camera's), ``arrived`` (perf_counter time of
    each frame's arrival), ``timestamps`` (the camera's, seconds), ``error`` (why the stream ended early, if it did).
    """

    live = True  # the SLAM loop grows its frame list from this dataset as it goes

    def __init__(self, camera, record: str | Path | None = None, max_frames: int | None = None):
        self.camera = camera
        self.intrinsics, self.distortion, self.depth_scale = camera.open()
        self.max_frames = max_frames
        self.timestamps: list[float] = []
        self.arrived: list[float] = []
        self._frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._taken: set[int] = set()
        self._cond = threading.Condition()
        self._ended = False
        self.error = ""
        self.writer = None
        if record is not None:
            from slam.data.tum_writer import TUMWriter

            self.writer = TUMWriter(record, self.intrinsics, distortion=self.distortion,
                                    depth_scale=self.depth_scale)
        self._thread = threading.Thread(target=self._receive, name="lrslam-camera", daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------------------------------------- receiving
    def _receive(self) -> None:
        try:
            while not self._ended and (self.max_frames is None or len(self.arrived) < self.max_frames):
                got = self.camera.read()
                if got is None:
                    break
                t, rgb, depth = got
                rgb, depth = np.ascontiguousarray(rgb, np.uint8), np.ascontiguousarray(depth, np.uint16)
                with self._cond:
                    if self._ended:  # stopped while the camera was delivering this one: the stream ended before it
                        break
                    i = len(self.arrived)
                    self._frames[i] = (rgb, depth)
                    self.timestamps.append(float(t))
                    self.arrived.append(time.perf_counter())
                    for old in [j for j in self._frames if j < i - KEEP_UNTAKEN and j not in self._taken]:
                        del self._frames[old]
                    self._cond.notify_all()
                if self.writer is not None:
                    self.writer.add(float(t), rgb, depth)
        except Exception as exc:  # noqa: BLE001 - a camera that fails ends the stream; the run keeps what it has
            self.error = f"{type(exc).__name__}: {exc}"
            log.warning("camera: %s; the run ends with the frames received", self.error)
        finally:
            with self._cond:
                self._ended = True
                self._cond.notify_all()

    def wait_beyond(self, n: int) -> int:
        """Wait until more than ``n`` frames have arrived or the stream has ended; returns how many have arrived."""
        with self._cond:
            while not (len(self.arrived) > n or self._ended):
                self._cond.wait(0.2)  # in slices: a signal handler (Ctrl-C: stop) runs between them
            return len(self.arrived)

    def stop(self) -> None:
        """End the stream now (no blocking: a signal handler's work); :meth:`close` then releases the camera."""
        with self._cond:
            self._ended = True
            self._cond.notify_all()

    @property
    def ended(self) -> bool:
        """Whether no more frames will come (the camera's end, :meth:`close`, ``max_frames`` or an error)."""
        return self._ended

    def close(self) -> None:
        """Stop receiving (the frames received stay readable), close the camera and finish the recording.
        Safe to call twice, and from a signal handler's thread."""
        self.stop()
        self._thread.join(timeout=5)
        try:
            self.camera.close()
        finally:
            if self.writer is not None:
                writer, self.writer = self.writer, None
                writer.close()

    # ------------------------------------------------------------------------------------------ as a dataset
    def __len__(self) -> int:
        return len(self.arrived)

    def __getitem__(self, i: int) -> Frame:
        with self._cond:
            got = self._frames.get(i)
            if got is not None:
                self._taken.add(i)
        if got is None:
            raise SlamInputError(f"live frame {i} is no longer held (only the newest {KEEP_UNTAKEN} frames not "
                                 "taken are kept)")
        rgb, depth = got
        return Frame(index=i, timestamp=self.timestamps[i], color=torch.from_numpy(rgb).float() / 255.0,
                     depth=torch.from_numpy(depth.astype(np.float32) / np.float32(self.depth_scale)),
                     pose=torch.full((4, 4), float("nan")), intrinsics=self.intrinsics)


class RealSense:
    """An Intel RealSense (D400 / L500) through ``pyrealsense2``: colour and depth at ``width x height`` and
    ``fps``, depth aligned to colour on the host, the colour stream's intrinsics and the device's depth scale."""

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, warmup: int = 15):
        self.width, self.height, self.fps, self.warmup = width, height, fps, warmup
        self._pipeline = self._align = None

    def open(self) -> tuple[Intrinsics, list[float] | None, float]:
        try:
            import pyrealsense2 as rs
        except ImportError:
            raise SlamInputError("a RealSense camera needs pyrealsense2: pip install -e \".[realsense]\"") from None
        pipeline, config = rs.pipeline(), rs.config()
        config.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
        config.enable_stream(rs.stream.color, self.width, self.height, rs.format.rgb8, self.fps)
        try:
            profile = pipeline.start(config)
        except RuntimeError as exc:
            raise SlamInputError(f"no RealSense camera could be started at {self.width}x{self.height} {self.fps} Hz "
                                 f"({exc})") from None
        self._pipeline, self._align = pipeline, rs.align(rs.stream.color)
        k = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        intr = Intrinsics(float(k.fx), float(k.fy), float(k.ppx), float(k.ppy), int(k.height), int(k.width))
        coeffs = [float(c) for c in k.coeffs]
        distortion = coeffs if any(coeffs) and k.model == rs.distortion.brown_conrady else None
        depth_scale = 1.0 / profile.get_device().first_depth_sensor().get_depth_scale()
        for _ in range(self.warmup):  # auto-exposure settles
            pipeline.wait_for_frames()
        return intr, distortion, depth_scale

    def read(self):
        try:
            fs = self._align.process(self._pipeline.wait_for_frames())
        except RuntimeError as exc:  # the device was unplugged, or stopped delivering
            raise SlamInputError(f"the RealSense camera stopped delivering frames ({exc})") from None
        color, depth = fs.get_color_frame(), fs.get_depth_frame()
        if not color or not depth:
            return self.read()
        return (color.get_timestamp() / 1000.0, np.asanyarray(color.get_data()).copy(),
                np.asanyarray(depth.get_data()).copy())

    def close(self) -> None:
        if self._pipeline is not None:
            pipeline, self._pipeline = self._pipeline, None
            pipeline.stop()
