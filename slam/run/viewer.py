"""Live view of a SLAM run in Rerun (https://rerun.io): an :class:`slam.engine.observers.Observer` that logs as the run goes.

What is logged, on the ``frame`` timeline (the dataset's frame index):

* ``world``: view coordinates (the world axis nearest the first camera's up), static.
* ``world/camera``: ``Transform3D``, the estimated camera-to-world pose of the current frame.
* ``world/camera/image``: ``Pinhole`` (OpenCV axes, ``camera_xyz=RDF``), static: the frustum.
* ``world/camera/image/rgb``: the colour frame (``Image``, uint8 ``[H, W, 3]``; JPEG with ``jpeg_quality``).
* ``world/camera/image/depth``: the depth frame (``DepthImage``, uint16 millimetres, ``meter=1000``).
* ``world/trajectory/estimated``, ``world/trajectory/ground_truth``: ``LineStrips3D`` of the camera centres
  so far (metres), growing by one point a frame; ground truth only where it is finite.
* ``world/trajectory/corrected``, ``world/loops``: with loop closure, at the end: the corrected trajectory and a
  segment between the two frames of each loop (``LineStrips3D``, metres).
* ``world/mesh``: ``Mesh3D`` with vertex colours, the final mesh (and an optional preview every N keyframes).
* ``world/scene_box``: ``Boxes3D``, the fields' box, logged at the start and again on every frame it grew.
* ``metrics/ate_cm``: live ATE RMSE in cm (``Scalars``; frames where it is NaN are not logged);
  ``metrics/frame_time_s``: the frame's wall time in seconds; ``metrics/parameters``, ``metrics/field_bytes``: the
  scene's size after the frame (it changes where the box grew).

``rerun-sdk`` is an optional dependency (the ``viewer`` extra): :func:`require_rerun` raises
:class:`slam.errors.SlamInputError` naming the install command when it is missing.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import torch

from slam.errors import SlamInputError
from slam.engine.observers import FrameRecord, Observer

#: where ``rerun`` (the viewer) listens by default
DEFAULT_CONNECT = "rerun+http://127.0.0.1:9876/proxy"

_EST_COLOR = (255, 140, 0)
_GT_COLOR = (40, 180, 60)
_LOOP_COLOR = (200, 40, 200)
_LINE_RADIUS = -2.0  # negative: 2 UI points wide at any zoom, visible around a room and around a desk alike


def require_rerun():
    """Import and return ``rerun``; SlamInputError with the install command if it is not installed."""
    try:
        import rerun
    except ImportError:
        from slam._deps import install_command

        raise SlamInputError(f"the Rerun viewer needs rerun-sdk, which is not installed; install the viewer extra: "
                             f"{install_command('viewer')} (or: python3 -m pip install \"rerun-sdk>=0.24\")") from None
    return rerun


def check_recording_path(path: str | Path) -> Path:
    """Make sure a recording can be written at ``path`` (creating its folder); SlamInputError naming why not.

    Checked by actually opening the file, because permissions alone do not tell (root, read-only mounts).
    """
    p = Path(path).expanduser()
    if p.is_dir():
        raise SlamInputError(f"--rerun {p}: is a folder; give a file name such as {p / 'run.rrd'}")
    existed = p.exists()
    anc = p.parent
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise SlamInputError(f"--rerun {p}: cannot write the recording there ({anc} is a file, not a folder)")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "ab"):
            pass
    except OSError as exc:
        raise SlamInputError(f"--rerun {p}: cannot write the recording there ({exc.strerror or exc})") from None
    if not existed:
        p.unlink()
    return p


def _up_axis(c2w0: torch.Tensor):
    """The world axis nearest the first camera's up (-y in OpenCV axes), as Rerun view coordinates.

    Datasets disagree on the world frame (the synthetic room is z-up, TUM relative to the first camera is
    y-down), and a 3D view with the wrong up axis is hard to navigate; a hand-held or robot camera starts
    roughly level, so its up direction picks the right one for both.
    """
    import rerun as rr

    up = -c2w0[:3, 1].double()
    axis = int(torch.argmax(up.abs()))
    sign = "UP" if float(up[axis]) > 0 else "DOWN"
    return getattr(rr.ViewCoordinates, f"RIGHT_HAND_{'XYZ'[axis]}_{sign}")


def default_blueprint():
    """3D view of the world (mesh, trajectories, camera with its colour frame) next to the colour and depth frames
    and the two time series."""
    import rerun.blueprint as rrb

    parts = []
    try:
        # follow the newest frame: live, the view keeps up with the run; from a file, it opens at the end
        # (the final mesh) instead of replaying from frame 0
        parts.append(rrb.TimePanel(timeline="frame", play_state="following", state="collapsed"))
    except TypeError:  # rerun-sdk < 0.25 has no playback settings in the blueprint
        pass
    return rrb.Blueprint(
        rrb.Horizontal(
            # the depth frame stays out of the 3D view: drawn there as a point cloud it hides the mesh
            rrb.Spatial3DView(origin="world", contents=["+ $origin/**", "- /world/camera/image/depth"], name="scene"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="world/camera/image", contents="$origin/rgb", name="colour"),
                rrb.Spatial2DView(origin="world/camera/image", contents="$origin/depth", name="depth"),
                rrb.TimeSeriesView(origin="metrics/ate_cm", name="live ATE RMSE (cm)"),
                rrb.TimeSeriesView(origin="metrics/frame_time_s", name="frame time (s)"),
            ),
            column_shares=[3, 2],
        ),
        *parts,
        collapse_panels=True,
    )


class _Track:
    """Camera centres so far, ``[n, 3]`` float32 in a buffer that doubles when full: appending and handing the
    whole strip to Rerun stay cheap on sequences of thousands of frames (no Python lists to convert)."""

    def __init__(self):
        self.buf = np.zeros((64, 3), dtype=np.float32)
        self.n = 0

    def append(self, xyz) -> np.ndarray:
        if self.n == len(self.buf):
            self.buf = np.concatenate([self.buf, np.zeros_like(self.buf)])
        self.buf[self.n] = xyz
        self.n += 1
        return self.buf[: self.n]


class RerunObserver(Observer):
    """Log a run to a ``.rrd`` file and/or a running Rerun viewer.

    Args:
        save: recording file to write (``.rrd``), or None.
        connect: gRPC address of a running viewer (e.g. :data:`DEFAULT_CONNECT`), or None.
        images_every: log the colour and depth frames every N frames (1 = every frame); poses, trajectories
            and scalars are logged every frame regardless.
        jpeg_quality: JPEG-compress the colour frames at this quality (1-100); None logs them raw.
        mesh_every: also extract and log an unculled preview mesh after every N-th keyframe (0 = only the final
            mesh). Each preview costs a marching-cubes pass over the scene (seconds on a CPU).
        application_id: Rerun application id (groups recordings in the viewer).
    """

    def __init__(self, save: str | Path | None = None, connect: str | None = None, images_every: int = 1,
                 jpeg_quality: int | None = None, mesh_every: int = 0, application_id: str = "lrslam"):
        if save is None and connect is None:
            raise SlamInputError("the Rerun viewer needs a recording file (--rerun FILE.rrd) or a viewer address")
        if images_every < 1:
            raise SlamInputError(f"--rerun-images-every must be >= 1, got {images_every}")
        if jpeg_quality is not None and not 1 <= jpeg_quality <= 100:
            raise SlamInputError(f"--rerun-jpeg must be in 1..100, got {jpeg_quality}")
        if mesh_every < 0:
            raise SlamInputError(f"--rerun-mesh-every must be >= 0, got {mesh_every}")
        rr = require_rerun()
        self.rr = rr
        self.images_every, self.jpeg_quality, self.mesh_every = images_every, jpeg_quality, mesh_every
        self.save = None if save is None else Path(save).expanduser()
        self.connect, self.application_id = connect, application_id
        self.rec = None
        self._est = _Track()
        self._gt = _Track()
        self._keyframes_seen = 0
        self._box = None  # the scene box last logged
        #: wall seconds spent in this observer's logging calls (on_start, on_frame, on_finish, close)
        self.log_s = 0.0

    # ------------------------------------------------------------------------------------------- observer
    def on_start(self, run) -> None:
        t0 = time.perf_counter()
        self._start(run)
        self.log_s += time.perf_counter() - t0

    def on_frame(self, run, record: FrameRecord) -> None:
        t0 = time.perf_counter()
        self._frame(run, record)
        self.log_s += time.perf_counter() - t0

    def on_finish(self, run, metrics: dict, mesh=None) -> None:
        t0 = time.perf_counter()
        self.rec.set_time("frame", sequence=int(run.indices[run.done - 1]))
        if mesh is not None and len(mesh.faces):
            self._log_mesh(mesh)
        if run.state.corrected is not None:  # loop closure: the corrected trajectory and an edge per loop
            pos = run.poses()[:, :3, 3]
            at = {int(i): k for k, i in enumerate(run.indices[: run.done])}
            edges = [[pos[at[e["frame"]]], pos[at[e["with_frame"]]]] for e in run.state.events
                     if e.get("event") == "loop closed"]
            self.rec.log("world/trajectory/corrected", self.rr.LineStrips3D([pos], colors=[_LOOP_COLOR],
                                                                            radii=[_LINE_RADIUS]))
            self.rec.log("world/loops", self.rr.LineStrips3D(edges, colors=[_LOOP_COLOR], radii=[_LINE_RADIUS]))
        self.log_s += time.perf_counter() - t0

    def close(self) -> None:
        if self.rec is None:
            return
        t0 = time.perf_counter()
        rec, self.rec = self.rec, None
        rec.flush()
        rec.disconnect()
        self.log_s += time.perf_counter() - t0

    # ------------------------------------------------------------------------------------------- helpers
    def _start(self, run) -> None:
        rr, intr = self.rr, run.intrinsics
        # the sinks open here, not in __init__, so a run that fails while loading its data leaves no file
        rec = self.rec = rr.RecordingStream(self.application_id)
        sinks = []
        if self.save is not None:
            sinks.append(rr.FileSink(str(self.save)))
        if self.connect is not None:
            sinks.append(rr.GrpcSink(self.connect))
        rec.set_sinks(*sinks, default_blueprint=default_blueprint())
        rec.log("world", _up_axis(run.c2w0), static=True)
        # image_plane_distance sets the drawn frustum's depth: 0.2 m reads well at room scale
        rec.log("world/camera/image", rr.Pinhole(focal_length=[intr.fx, intr.fy], principal_point=[intr.cx, intr.cy],
                                                 width=intr.width, height=intr.height,
                                                 camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.2),
                static=True)
        done = run.done
        if done:  # a resumed run: its trajectory so far, so the strips carry on from it
            for T in run.poses():
                self._est.append(T[:3, 3].astype(np.float64))
            if run.gt is not None:
                for g in run.gt[:done]:
                    if bool(torch.isfinite(g).all()):
                        self._gt.append(g[:3, 3].double().numpy())
        rec.log("metrics/ate_cm", rr.SeriesLines(names="live ATE RMSE (cm)", colors=[_EST_COLOR]), static=True)
        rec.log("metrics/frame_time_s", rr.SeriesLines(names="frame time (s)"), static=True)

    def _frame(self, run, record: FrameRecord) -> None:
        rr, rec = self.rr, self.rec
        rec.set_time("frame", sequence=record.frame)
        pose = record.pose.detach().double().cpu().numpy()
        rec.log("world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        # the strip is re-sent whole each frame, so a viewer scrubbing the timeline sees it grow
        rec.log("world/trajectory/estimated",
                rr.LineStrips3D([self._est.append(pose[:3, 3])], colors=[_EST_COLOR], radii=[_LINE_RADIUS]))
        if record.gt is not None and bool(torch.isfinite(record.gt).all()):
            gt = self._gt.append(record.gt[:3, 3].double().cpu().numpy())
            rec.log("world/trajectory/ground_truth", rr.LineStrips3D([gt], colors=[_GT_COLOR], radii=[_LINE_RADIUS]))
        if record.k % self.images_every == 0:
            self._log_images(record)
        if math.isfinite(record.ate_m):
            rec.log("metrics/ate_cm", rr.Scalars(record.ate_m * 100.0))
        if math.isfinite(record.dt):
            rec.log("metrics/frame_time_s", rr.Scalars(record.dt))
        self._log_box(run)
        size = run.state.sizes[record.k] if record.k < len(run.state.sizes) else None
        if size:
            rec.log("metrics/parameters", rr.Scalars(float(size[0])))
            rec.log("metrics/field_bytes", rr.Scalars(float(size[1])))
        if self.mesh_every and record.mapped:
            n = run.keyframe_count
            if n > self._keyframes_seen:
                self._keyframes_seen = n
                if n % self.mesh_every == 0:
                    from slam.model.mesher import run_mesh

                    # unculled: culling needs every frame's pose, and the run is not over
                    self._log_mesh(run_mesh(run, cull=False))

    def _log_box(self, run) -> None:
        box = run.aabb.detach().cpu().double().numpy()
        if self._box is None or not np.array_equal(box, self._box):
            self._box = box
            self.rec.log("world/scene_box", self.rr.Boxes3D(mins=[box[:, 0]], sizes=[box[:, 1] - box[:, 0]]))

    def _log_images(self, record: FrameRecord) -> None:
        rr, rec = self.rr, self.rec
        if record.color is not None:
            rgb = (record.color.detach().clamp(0, 1) * 255 + 0.5).to(torch.uint8).cpu().numpy()
            img = rr.Image(rgb)
            rec.log("world/camera/image/rgb", img.compress(self.jpeg_quality) if self.jpeg_quality else img)
        if record.depth is not None:
            # millimetres in uint16 halve the float32 bytes and keep TUM/Kinect depth's own resolution
            mm = (record.depth.detach() * 1000.0 + 0.5).clamp(0, 65535).to(torch.int32).cpu().numpy().astype(np.uint16)
            rec.log("world/camera/image/depth", rr.DepthImage(mm, meter=1000.0))

    def _log_mesh(self, mesh) -> None:
        rr = self.rr
        colors = None
        vc = getattr(getattr(mesh, "visual", None), "vertex_colors", None)
        if vc is not None and len(vc) == len(mesh.vertices):
            colors = np.asarray(vc)[:, :3]
        self.rec.log("world/mesh", rr.Mesh3D(vertex_positions=np.asarray(mesh.vertices, dtype=np.float32),
                                             triangle_indices=np.asarray(mesh.faces, dtype=np.uint32),
                                             vertex_colors=colors))
