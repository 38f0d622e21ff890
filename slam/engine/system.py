"""The SLAM loop: tracking every frame, mapping every ``every_frame`` frames (and the last), keyframes, mesh
extraction. Writing a run's outputs lives in :mod:`slam.run.outputs`, a whole run to a folder in :mod:`slam.run.runner`.

Frames are read ahead on a background thread (:mod:`slam.engine.frames`); mapping runs inline (sequential, ESLAM's
effective schedule) or beside the tracker (``parallel``), both deterministic (:mod:`slam.engine.map_worker`).

Robustness: a frame that cannot be read, or has no valid depth, is not tracked or mapped (its pose is the
prediction: constant velocity, or the previous pose); a tracking result that is not finite falls back to the
prediction and the frame is not mapped; a mapping step whose loss or gradient is not finite is skipped, so the map
is never written with NaNs. Each such event is logged and listed in ``metrics.json``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from slam.config import Config
from slam.errors import SlamInputError
from slam.engine.frames import FrameSource
from slam.engine.keyframes import KeyframeStore
from slam.engine.map_worker import MapJob, MapWorker
from slam.core.pose import constant_velocity, matrix_to_pose, pose_to_matrix
from slam.engine.observers import FrameRecord, Observer
from slam.engine.runtime import keep_freed_memory, set_threads
from slam.engine.setup import auto_bound, frame_indices
from slam.model.scene import SceneModel, scene_aabb
from slam.engine.recovery import TrackInput, icp_start, recover, relocalise
from slam.engine.tracker import track_frame
from slam.engine.tracking_guard import TrackingGuard

log = logging.getLogger("slam")


# --------------------------------------------------------------------------------------------------- loop
@dataclass
class RunState:
    """Everything the loop accumulates (and a checkpoint keeps): one entry per processed frame in ``est``
    (``[7]`` poses), ``trusted`` (False where tracking was lost or the frame was skipped) and ``frame_times``
    (seconds); ``events`` (skipped frames, fallbacks, recoveries); ``bad_frames`` (unreadable frames)."""

    est: list = field(default_factory=list)
    trusted: list = field(default_factory=list)
    frame_times: list = field(default_factory=list)
    events: list = field(default_factory=list)
    bad_frames: int = 0
    initialized: bool = False  # the first-frame warm-up has run (on the first frame with depth)
    prev_depth_k: int = -1  # position of the last trusted frame with depth (ICP's reference)
    reloc_tried_at: int = -1  # position of the last relocalisation attempt
    tracking: list = field(default_factory=list)  # per tracked frame: loss, iterations, inlier share


class TooManyBadFrames(SlamInputError):
    """More than ``data.max_bad_fraction`` of the frames read so far could not be read."""


def _check_edges(cfg: Config, height: int, width: int) -> None:
    """``tracking.ignore_edge`` must leave pixels to track in the working image (it is only known once the first
    frame is read, so the config loader cannot check it)."""
    rows, cols = cfg.tracking.ignore_edge
    if 2 * rows >= height or 2 * cols >= width:
        raise SlamInputError(
            f"config key 'tracking.ignore_edge' = {cfg.tracking.ignore_edge} leaves no pixel to track in the "
            f"{height}x{width} working image: rows must be < {(height + 1) // 2}, columns < {(width + 1) // 2}")


class SLAM:
    """Tracking + mapping over a dataset with one scene model.

    Args:
        cfg: resolved config.
        dataset: a ``slam.data`` dataset.
        device: torch device.
    """

    def __init__(self, cfg: Config, dataset, device: torch.device | str = "cpu"):
        self.cfg = cfg
        self.ds = dataset
        self.device = torch.device(device)
        self.indices = frame_indices(len(dataset), cfg)
        set_threads(cfg.threads)
        if cfg.keep_freed_memory:
            keep_freed_memory()
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        # separate streams for the tracker and the mapper: the same draws whichever runs first (parallel mode)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.map_gen = torch.Generator().manual_seed(cfg.seed + 7919)
        gt = getattr(dataset, "gt_poses", None)
        self.gt = None if gt is None else torch.as_tensor(np.asarray(gt), dtype=torch.float32)[self.indices]
        self.state = RunState()
        first = self._first_readable()
        self.intr = first.intrinsics
        _check_edges(cfg, self.intr.height, self.intr.width)
        self.c2w0, self.c2w0_source = self._initial_pose()
        if cfg.scene.bound == "auto":
            k = max(1, min(cfg.scene.bound_auto_frames, len(self.indices)))
            depths = [first.depth] + [self._depth_or_none(i) for i in range(1, k)]
            self.bound = auto_bound([d for d in depths if d is not None], self.c2w0, cfg.scene.bound_auto_percentile,
                                    cfg.scene.bound_auto_margin)
            log.info("bound=auto -> %s", [[round(v, 3) for v in r] for r in self.bound])
        else:
            self.bound = [list(map(float, r)) for r in cfg.scene.bound]
        self.mc_bound = cfg.scene.marching_cubes_bound or self.bound
        self.aabb = scene_aabb(self.bound, cfg.scene.bound_dividable)
        self.scene = SceneModel(cfg, self.aabb).to(self.device)
        self.keyframes = KeyframeStore(storage=cfg.mapping.keyframe_storage, max_keyframes=cfg.mapping.max_keyframes)
        self.frames = FrameSource(dataset, self.indices, (self.intr.height, self.intr.width), self.device,
                                  ahead=cfg.data.prefetch)
        self.mapper = MapWorker(self.scene, self.keyframes, cfg, self.intr, self.map_gen, parallel=cfg.parallel)
        self._prev_depth: torch.Tensor | None = None  # depth of the last frame with depth (ICP's reference)
        self.guard = TrackingGuard(cfg.tracking)

    # ------------------------------------------------------------------------------------------------ set-up
    def _first_readable(self):
        """The first frame that loads (its intrinsics and depth set up the run); bad ones before it are events."""
        last_exc = None
        for k, i in enumerate(self.indices[: max(1, int(len(self.indices) * self.cfg.data.max_bad_fraction) + 1)]):
            try:
                return self.ds[i]
            except (SlamInputError, OSError, ValueError) as exc:
                last_exc = exc
                log.warning("frame %d: unreadable (%s)", i, exc)
        raise SlamInputError(f"no readable frame at the start of the sequence: {last_exc}")

    def _depth_or_none(self, k: int):
        try:
            return self.ds[self.indices[k]].depth
        except (SlamInputError, OSError, ValueError):
            return None

    def _initial_pose(self) -> tuple[torch.Tensor, str]:
        """Frame 0's camera-to-world: its ground truth when finite (ESLAM pins frame 0 to it), else the first
        finite ground-truth pose of the sequence (ScanNet marks some as invalid), else the identity."""
        if self.gt is not None:
            ok = torch.isfinite(self.gt).flatten(1).all(1)
            if bool(ok[0]):
                return self.gt[0].clone(), "ground truth"
            if bool(ok.any()):
                j = int(torch.nonzero(ok)[0])
                return self.gt[j].clone(), f"ground truth of frame {self.indices[j]} (frame {self.indices[0]}'s is invalid)"
        return torch.eye(4), "identity (no ground truth)"

    # ----------------------------------------------------------------------------------------------- helpers
    def live_ate(self) -> float:
        if self.gt is None or len(self.state.est) < 3:
            return float("nan")
        from slam.eval import ate

        est = pose_to_matrix(torch.stack(self.state.est)).numpy()
        try:
            return ate(est, self.gt[: len(est)].numpy()).rmse
        except SlamInputError:
            return float("nan")

    def _event(self, k: int, what: str, **extra) -> None:
        log.warning("frame %d: %s", self.indices[k], what)
        self.state.events.append({"frame": int(self.indices[k]), "event": what, **extra})

    def _prediction(self, k: int) -> tuple[torch.Tensor, str]:
        """The pose frame ``k`` starts from before tracking, and what it is."""
        est = self.state.est
        if self.cfg.tracking.init != "previous" and k >= 2:
            return constant_velocity(est[-1], est[-2]), "constant-velocity pose"
        return est[-1].clone(), "previous pose"

    def _apply(self, done) -> None:
        """Results of finished mapping calls: the BA-refined pose of the mapped frame, events."""
        for d in done:
            k = d.job.k
            if not d.result.ok:
                self._event(k, "mapping call failed: no finite loss in any iteration, map unchanged")
            elif k > 0:
                self.state.est[k] = d.result.pose.cpu()
            if d.result.skipped:
                self._event(k, f"mapping: {d.result.skipped} step(s) skipped (non-finite loss or gradient)")

    def _dt(self, k: int, j: int | None = None) -> float:
        """Seconds from frame ``j`` (default ``k - 1``) to frame ``k`` (30 Hz per dataset frame without
        timestamps)."""
        j = max(k - 1, 0) if j is None else j
        ts = getattr(self.ds, "timestamps", None)
        if ts is None or k == 0:
            return (self.indices[k] - self.indices[j]) / 30.0
        return float(ts[self.indices[k]]) - float(ts[self.indices[j]])

    def _last_trusted(self) -> int:
        """Position of the last trusted frame (-1: none yet)."""
        tr = self.state.trusted
        return next((j for j in range(len(tr) - 1, -1, -1) if tr[j]), -1)

    def _track(self, k: int, frame, pred: torch.Tensor, what: str):
        """Track frame ``k`` from the ICP start (or ``pred``), check it, recover or relocalise
        (:mod:`slam.engine.recovery`). Returns ``(result, trusted)``."""
        cfg, st = self.cfg, self.state
        init = pred
        if cfg.tracking.init == "icp" and self._prev_depth is not None:
            # ICP registers against the last trusted frame with depth: chain its motion onto that frame's pose
            init, _ = icp_start(st.est[st.prev_depth_k], self._prev_depth, pred, frame.depth, self.intr)
        inp = TrackInput(self.mapper.track_scene, frame.color, frame.depth, self.intr, cfg, self.gen, self.guard)
        res = track_frame(inp.scene, frame.color, frame.depth, self.intr, init, cfg, self.gen)
        last = self._last_trusted()
        anchor, dt = (st.est[last], self._dt(k, last)) if last >= 0 else (st.est[-1], self._dt(k))
        if not res.ok:
            res.pose, trusted, lost = pred, False, f"tracking failed ({res.message}): {what} used"
        else:
            starts = {"start": init, what: pred, "previous pose": st.est[-1]}
            if 0 <= last < k - 1:
                starts["last trusted pose"] = st.est[last]
            res, trusted, lost = recover(inp, res, anchor, dt, starts, pred, lambda m, **x: self._event(k, m, **x))
        if trusted:
            return res, True
        untrusted = k - 1 - last  # frames in a row before this one without a trusted pose
        n = cfg.tracking.relocalize_after
        if n and last >= 0 and untrusted >= n and (st.reloc_tried_at <= last or k - st.reloc_tried_at >= n):
            best, found = self._relocalise(k, inp, anchor, dt, pred)
            if best is not None:
                self._event(k, f"{lost}; relocalised from the {found} after {untrusted} untrusted frames "
                               "(loss history restarted)", relocalised=True)
                best.iters += res.iters
                return best, True
            lost += f"; relocalisation after {untrusted} untrusted frames found no plausible pose"
        self._event(k, f"{lost}, frame not mapped", lost=True)
        return res, False

    def _relocalise(self, k: int, inp: TrackInput, anchor: torch.Tensor, dt: float, pred: torch.Tensor):
        """Relocalise frame ``k`` against the keyframes (read once the mapper is idle, so the same ones whatever
        the threads' timing). Returns ``(result or None, the start it came from)``."""
        self.state.reloc_tried_at = k
        self.mapper.wait_idle()
        kfs = list(self.keyframes.frames)
        if not kfs:
            return None, ""
        best, found = relocalise(inp, kfs, anchor, dt, pred, lambda j: int(self.indices[j]))
        if best is not None:
            self.guard.reset(best.loss)
        return best, found

    def _check_bad_frames(self) -> None:
        n, total = len(self.state.est), len(self.indices)
        if self.state.bad_frames > self.cfg.data.max_bad_fraction * total:
            raise TooManyBadFrames(
                f"{self.state.bad_frames} of the first {n} frames could not be read, more than "
                f"data.max_bad_fraction = {self.cfg.data.max_bad_fraction} of the {total} frames; see the events")

    # ------------------------------------------------------------------------------------------------- a frame
    def step(self, k: int) -> FrameRecord:
        """Process the k-th selected frame (track, then map if scheduled); returns what happened."""
        cfg = self.cfg
        st = self.state
        self._apply(self.mapper.sync(k))
        frame = self.frames.get(k)
        tracked = mapped = False
        trusted = True
        if not frame.ok:
            st.bad_frames += 1
            pose, what = (matrix_to_pose(self.c2w0), "initial pose") if k == 0 else self._prediction(k)
            self._event(k, f"unreadable frame skipped, {what} used: {frame.error}", bad_frame=True)
            trusted = False
        elif k == 0:
            pose = matrix_to_pose(self.c2w0)
            if self.c2w0_source != "ground truth":
                self._event(k, f"initial pose: {self.c2w0_source}")
            if not frame.has_depth:
                self._event(k, "no valid depth: the map starts at the first frame that has depth")
        elif not frame.has_depth or not st.initialized:
            pose, what = self._prediction(k)
            reason = "no valid depth" if not frame.has_depth else "no map yet (no earlier frame had depth)"
            self._event(k, f"{reason}: not tracked, {what} used")
            trusted = frame.has_depth  # the first frame with depth starts the map at this pose
        else:
            pred, what = self._prediction(k)
            res, trusted = self._track(k, frame, pred, what)
            tracked = True
            st.tracking.append({"frame": int(self.indices[k]), "loss": res.loss, "iters": res.iters,
                                "inliers": res.inliers, "trusted": trusted})
            pose = res.pose
        st.est.append(pose.cpu())
        st.trusted.append(trusted)
        last = k == len(self.indices) - 1
        if frame.ok and frame.has_depth and trusted:
            self._prev_depth = frame.depth
            st.prev_depth_k = k
            first = not st.initialized
            if first or k % cfg.mapping.every_frame == 0 or last:
                self.mapper.submit(MapJob(k, frame.color, frame.depth, st.est[-1], first=first,
                                          keyframe=first or k % cfg.mapping.keyframe_every == 0))
                st.initialized = True
                mapped = True
        if not self.mapper.parallel:
            self._apply(self.mapper.sync(k + 1))
        self._check_bad_frames()
        return FrameRecord(k=k, frame=int(self.indices[k]), color=frame.color, depth=frame.depth,
                           pose=pose_to_matrix(st.est[-1]), gt=self.gt[k] if self.gt is not None else None,
                           tracked=tracked, mapped=mapped)

    def finish(self) -> None:
        """Wait for the mapper and apply its last results: at the end of the sequence, before the final outputs.
        Never on a stop: a checkpoint keeps the pending calls instead (:mod:`slam.run.checkpoint`), so a resumed run
        applies them on the frames the uninterrupted run would have."""
        self._apply(self.mapper.drain())

    def close(self, abort: bool = False) -> None:
        """Stop the reader and the mapper threads; ``abort`` (a second Ctrl-C) ends a mapping call in progress at
        its next iteration instead of waiting for it."""
        self.frames.close()
        self.mapper.close(abort=abort)

    def run(self, progress: bool = True, observers: Sequence[Observer] = (), start: int | None = None,
            should_stop=None, on_frame=None) -> RunState:
        """Process the selected frames from ``start`` (default: where the state left off), with a progress bar
        (frame, live ATE, frame time) and the observers' ``on_frame`` after each one. After the last frame the
        mapper is drained (:meth:`finish`); a loop ended by ``should_stop`` or an exception leaves the pending
        mapping calls queued, as the schedule has them.

        Args:
            should_stop: called after each frame; True ends the loop early (an interrupt).
            on_frame: called after each frame with its position (periodic checkpoints).
        """
        from tqdm import tqdm

        start = len(self.state.est) if start is None else start
        bar = tqdm(range(start, len(self.indices)), disable=not progress, unit="frame", dynamic_ncols=True,
                   desc=f"lrslam [{self.cfg.representation}]", initial=start, total=len(self.indices))
        try:
            for k in bar:
                t0 = time.perf_counter()
                rec = self.step(k)
                dt = time.perf_counter() - t0
                self.state.frame_times.append(dt)
                rec.dt = dt
                rec.ate_m = self.live_ate()
                for obs in observers:
                    obs.on_frame(self, rec)
                bar.set_postfix_str(f"frame {self.indices[k]}  ATE {rec.ate_m * 100:.2f} cm  {dt:.2f} s/frame")
                if on_frame is not None:
                    on_frame(k)
                if should_stop is not None and k + 1 < len(self.indices) and should_stop():
                    return self.state
        finally:
            bar.close()
        self.finish()
        return self.state

    # ----------------------------------------------------------------------------------------------- results
    def poses_matrix(self) -> np.ndarray:
        return pose_to_matrix(torch.stack(self.state.est)).numpy()

    def keyframe_poses(self) -> np.ndarray:
        return pose_to_matrix(self.keyframes.poses()).numpy() if len(self.keyframes) else np.zeros((0, 4, 4))

    def mesh(self, resolution: float | None = None, cull: bool | None = None):
        """The run's mesh (:func:`slam.model.mesher.run_mesh`): marching cubes in the visibility hull, culled."""
        from slam.model.mesher import run_mesh

        return run_mesh(self, resolution, cull)

    def checkpoint_extra(self) -> dict:
        """What a scene checkpoint records of the run: poses, frames, bounds, intrinsics, keyframes, hull points."""
        from slam.model.mesher import run_hull_points

        ts = getattr(self.ds, "timestamps", None)
        return {
            "poses": torch.from_numpy(self.poses_matrix()).float(),
            "frame_indices": list(self.indices),
            "timestamps": [float(ts[i]) for i in self.indices] if ts is not None else [],
            "bound": self.bound,
            "marching_cubes_bound": [list(map(float, r)) for r in self.mc_bound],
            "aabb": self.aabb.tolist(),
            "intrinsics": self.intr.as_dict(),
            "keyframe_indices": [int(self.indices[kf.index]) for kf in self.keyframes.frames],
            "keyframe_poses": torch.from_numpy(self.keyframe_poses()).float(),
            "hull_points": torch.from_numpy(run_hull_points(self)).float(),
        }
