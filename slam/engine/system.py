"""The SLAM loop: tracking every frame, mapping every ``every_frame`` frames (and the last), keyframes.

A frame is: sync with the mapper, read, predict, track (with recovery, :mod:`slam.engine.tracking`), record,
submit for mapping. Writing a run's outputs and checkpoints lives in :mod:`slam.run`, which reads the run through
:meth:`SLAM.view` and saves and restores it through :meth:`SLAM.state_dict` / :meth:`SLAM.load_state_dict`.

Frames are read ahead (:mod:`slam.engine.frames`); mapping runs inline (ESLAM's schedule) or beside the tracker
(``parallel``), both deterministic (:mod:`slam.engine.map_worker`); loop closure (``loops``) watches beside the
tracker and corrects the trajectory at the end (:mod:`slam.loop`). A real-time run does not wait for the first
map: the frames that arrive meanwhile are tracked by depth odometry (``mapping.realtime_warmup``).

Robustness: an unreadable frame is not tracked or mapped (its pose is the prediction: constant velocity between two
trusted poses, or the previous pose); a frame without valid depth is tracked on its colour, not mapped
(``tracking.without_depth``); a non-finite tracking result falls back to the prediction, not mapped; a mapping step
whose loss or gradient is not finite is skipped (no NaN in the map). Each such event is logged, in ``metrics.json``."""

from __future__ import annotations

import logging
import time
from typing import Sequence

import numpy as np
import torch

from slam.config import Config
from slam.core.pose import matrix_to_pose, pose_to_matrix
from slam.engine.frames import FrameSource, LoadedFrame, first_readable
from slam.engine.growth_policy import SceneGrowth, grow_scene
from slam.engine.keyframes import KeyframeStore
from slam.engine.map_call import MapJob
from slam.engine.map_worker import MapWorker
from slam.engine.observers import FrameRecord, Observer
from slam.engine.recovery import TrackInput
from slam.engine.realtime import Replay, arrival_times, note_latency, take_next
from slam.engine.refine import follow_corrected
from slam.engine.rehearsal import preload
from slam.engine.runtime import float_fingerprint, keep_freed_memory, release_freed_memory, set_threads
from slam.engine.schedule import call_iters, is_keyframe
from slam.engine.setup import check_edges, frame_indices, initial_pose, scene_bound
from slam.engine.state import RunState, TooManyBadFrames, check_bad_frames, live_ate
from slam.engine.tracking import (Timeline, predict, track_by_odometry, track_with_recovery,
                                  track_without_depth)
from slam.engine.tracking_guard import TrackingGuard
from slam.engine.system_state import load_system_state, system_state
from slam.engine.view import RunView, view_of
from slam.loop.closer import close_run_loops, loop_closer
from slam.model.scene import SceneModel, scene_aabb, scene_size

log = logging.getLogger("slam")

__all__ = ["SLAM", "RunState", "TooManyBadFrames"]


class SLAM:
    """Tracking + mapping over a dataset with one scene model (``cfg``: the resolved config; ``dataset``: a
    ``slam.data`` dataset; ``device``: torch device)."""

    def __init__(self, cfg: Config, dataset, device: torch.device | str = "cpu"):
        self.cfg, self.ds, self.device = cfg, dataset, torch.device(device)
        self.indices = frame_indices(len(dataset), cfg)
        self.selection = list(self.indices)  # the frames selected; data.realtime passes over some (self.indices)
        set_threads(cfg.threads)
        float_fingerprint()  # taken now, before the mapper's thread runs: metrics.json records it
        if cfg.keep_freed_memory:
            keep_freed_memory()
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        # separate streams for the tracker and the mapper: the same draws whichever runs first (parallel mode)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.map_gen = torch.Generator().manual_seed(cfg.seed + 7919)
        gt = getattr(dataset, "gt_poses", None)
        self.gt = None if gt is None else torch.as_tensor(np.asarray(gt), dtype=torch.float32)[self.indices]
        ts = getattr(dataset, "timestamps", None)
        self.timestamps = None if ts is None else np.asarray([float(ts[i]) for i in self.indices])
        self.state = RunState()
        _, first = first_readable(dataset, self.indices, int(len(self.indices) * cfg.data.max_bad_fraction) + 1)
        self.intr = first.intrinsics
        check_edges(cfg, self.intr.height, self.intr.width)
        self.c2w0, self.c2w0_source = initial_pose(self.gt, self.indices)
        self.bound = scene_bound(cfg, dataset, self.indices, first.depth, self.c2w0)
        self.mc_bound = cfg.scene.marching_cubes_bound or self.bound
        self.aabb = scene_aabb(self.bound, cfg.scene.bound_dividable)
        self.scene = SceneModel(cfg, self.aabb).to(self.device)
        self.size = scene_size(self.scene)  # (parameters, field bytes), after each growth too
        self.keyframes = KeyframeStore.for_mapping(cfg.mapping)
        # a real-time replay or a live camera (a dataset that grows, slam.data.live) reads a frame once it is taken:
        # the frames read ahead might be passed over
        self.live = bool(getattr(dataset, "live", False))
        realtime = cfg.data.realtime or self.live
        self.frames = FrameSource(dataset, self.indices, (self.intr.height, self.intr.width), self.device,
                                  ahead=0 if realtime else cfg.data.prefetch,
                                  in_waits=cfg.data.prefetch_in == "waits" and not realtime)
        self.replay = Replay(arrival_times(self.selection, ts)) if realtime and not self.live else None
        t0 = time.perf_counter()
        frame0 = (first.color.to(self.device), first.depth.to(self.device), matrix_to_pose(self.c2w0))
        self.mapper, self.loops = None, loop_closer(cfg, self.intr)
        try:  # from here on a reader thread, a mapper thread or process and a spill file exist: a failure closes them
            self.mapper = MapWorker(self.scene, self.keyframes, cfg, self.intr, self.map_gen, parallel=cfg.parallel,
                                    rehearsal=frame0 if cfg.preload_kernels else None,
                                    free=realtime and cfg.mapping.realtime_sync == "free")
            preload(self.scene, cfg, self.intr, frame0, self.mapper)  # and waits for the mapper process's own
        except BaseException:
            self.close(abort=True)
            raise
        self.preload_s = time.perf_counter() - t0
        self.guard = TrackingGuard(cfg.tracking)
        self.odometry_first = self.mapper.free and cfg.mapping.realtime_warmup == "odometry"  # track_by_odometry
        self.timeline = Timeline(dt=self._dt, keyframes=self.keyframes_when_idle,
                                 frame_of=lambda j: int(self.indices[j]), event=self._event)
        auto = cfg.scene.bound == "auto"  # a cube around the first camera: its half-size is the reach it was sized to
        self.growth = SceneGrowth(cfg, self._event, radius=(self.bound[0][1] - self.bound[0][0]) / 2 if auto else None)

    # ----------------------------------------------------------------------------------------------- helpers
    def _event(self, k: int, what: str, level: int = logging.WARNING, **extra) -> None:
        log.log(level, "frame %d: %s", self.indices[k], what)
        self.state.events.append({"frame": int(self.indices[k]), "event": what, **extra})

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

    def _dt(self, k: int, j: int) -> float:
        """Seconds from frame position ``j`` to ``k`` (30 Hz per dataset frame without timestamps)."""
        if self.timestamps is None or k == 0:
            return (self.indices[k] - self.indices[j]) / 30.0
        return float(self.timestamps[k]) - float(self.timestamps[j])

    def _n_frames(self) -> int:
        """Frames in the run as far as the schedule knows: a live stream not ended has at least one more."""
        return len(self.indices) + (1 if self.live and not self.ds.ended else 0)

    def keyframes_when_idle(self) -> list:
        """The keyframes, once the mapper is idle (they are the mapper's while a call runs)."""
        self.mapper.wait_idle()
        return list(self.keyframes.frames)

    # ------------------------------------------------------------------------------------------------- a frame
    def step(self, k: int) -> FrameRecord:
        """Process the k-th selected frame (track, then map if scheduled); returns what happened."""
        odometry = self.odometry_first and self.mapper.applied < 2  # the map has not seen a frame beyond the first
        if not (odometry and self.mapper.busy(k)):  # never waits for the warm-up
            self._apply(self.mapper.sync(k, idle=self.frames.read_while))  # reads ahead while it waits (prefetch_in)
        warming = odometry and self.mapper.applied < 2
        if self.odometry_first and not warming:  # once: the frames before were tracked by depth odometry
            self.odometry_first = False
            self._event(k, "first map ready: tracked on the map from this frame on", logging.INFO)
        frame = self.frames.get(k)
        pose, tracked, trusted = self._pose(k, frame, warming)
        self.state.est.append(pose.cpu())
        self.state.trusted.append(trusted)
        mapped = self._submit(k, frame, trusted, warming)
        if warming and not mapped and self.mapper.applied and self.mapper.drained():  # no frame to bridge with (no
            self.odometry_first = False  # depth, or odometry failed): the tracker takes over on the first map
            self._event(k, "first map ready, no bridge frame: tracked on the map from the next frame", logging.INFO)
        self.state.sizes.append(list(self.size))
        if not self.mapper.parallel:
            self._apply(self.mapper.sync(k + 1))
        check_bad_frames(self.state, len(self.indices), self.cfg.data.max_bad_fraction)
        return FrameRecord(k=k, frame=int(self.indices[k]), color=frame.color, depth=frame.depth,
                           pose=pose_to_matrix(self.state.est[-1]), gt=self.gt[k] if self.gt is not None else None,
                           tracked=tracked, mapped=mapped)

    def _pose(self, k: int, frame: LoadedFrame, warming: bool) -> tuple[torch.Tensor, bool, bool]:
        """Frame ``k``'s pose ``[7]``, whether it was tracked and whether it is trusted (a frame that could not be
        tracked gets the prediction, untrusted; the first frame with depth starts the map, trusted); ``warming``:
        the first map is not built yet, depth odometry instead of the map (:func:`track_by_odometry`)."""
        st = self.state
        if not frame.ok:
            st.bad_frames += 1
            pose, what = ((matrix_to_pose(self.c2w0), "initial pose") if k == 0
                          else predict(st.est, st.trusted, self.cfg.tracking.init))
            self._event(k, f"unreadable frame skipped, {what} used: {frame.error}", bad_frame=True)
            return pose, False, False
        if k == 0:
            if self.c2w0_source != "ground truth":
                self._event(k, f"initial pose: {self.c2w0_source}")
            if not frame.has_depth:
                self._event(k, "no valid depth: the map starts at the first frame that has depth")
            return matrix_to_pose(self.c2w0), False, True
        pred, what = predict(st.est, st.trusted, self.cfg.tracking.init)
        if not st.initialized:
            reason = "no valid depth" if not frame.has_depth else "no map yet (no earlier frame had depth)"
            self._event(k, f"{reason}: not tracked, {what} used")
            return pred, False, frame.has_depth
        if warming:
            pose, ok = track_by_odometry(k, frame.depth if frame.has_depth else None, self.intr, st, pred, what,
                                         self.cfg, self.guard, self.timeline)
            return pose, frame.has_depth, ok
        inp = TrackInput(self.mapper.track_scene, frame.color, frame.depth, self.intr, self.cfg, self.gen, self.guard)
        if not frame.has_depth:
            return (*track_without_depth(k, inp, st, pred, what, self.timeline), False)
        res, trusted = track_with_recovery(k, inp, st, pred, what, self.timeline)
        st.tracking.append({"frame": int(self.indices[k]), "loss": res.loss, "iters": res.iters,
                            "inliers": res.inliers, "trusted": trusted})
        return res.pose, True, trusted

    def _submit(self, k: int, frame: LoadedFrame, trusted: bool, warming: bool) -> bool:
        """Queue the mapping call of frame ``k`` when the schedule maps it; returns whether it did. ``warming``:
        frame ``k`` was tracked by depth odometry; the first such frame once the warm-up call is applied is mapped
        as a keyframe (tracking goes on by odometry until that call has finished too, so the map reaches the camera)."""
        st, cfg = self.state, self.cfg
        if not (frame.ok and frame.has_depth and trusted) or (warming and not self.mapper.drained()):
            return False
        grow_scene(self, k, frame.depth)
        st.prev_depth, st.prev_depth_k = frame.depth, k
        if self.loops is not None:  # a loop keyframe, where the camera moved (slam.loop.closer): queued, not waited
            self.loops.offer(k, frame.color, frame.depth, pose_to_matrix(st.est[-1]).numpy(), trusted)
        first = not st.initialized
        iters = 0 if warming else call_iters(k, st, cfg.mapping, self._n_frames())
        if iters is None or self.mapper.declines(first):  # declines: a real-time run's busy mapper (map_worker)
            return False
        st.last_mapped = k
        keyframe = warming or is_keyframe(k, st, cfg.mapping, first)
        if keyframe:
            st.last_keyframe = k
        self.mapper.submit(MapJob(k, frame.color, frame.depth, st.est[-1], first=first, keyframe=keyframe,
                                  iters=iters))
        st.initialized = True
        return True

    def finish(self, progress: bool = False) -> None:
        """Wait for the mapper and apply its last results, then close the loops and refine the map on them (with a
        bar when ``progress``): at the end of the sequence, before the outputs. Never on a stop: a checkpoint keeps the
        pending calls instead, so a resumed run applies them where the uninterrupted run would (slam.run.checkpoint)."""
        self._apply(self.mapper.drain())
        if self.loops is not None and self.state.est:
            odometry = pose_to_matrix(torch.stack(self.state.est)).numpy()
            close_run_loops(self.loops, self.state, self.indices, odometry)
            follow_corrected(self, odometry, progress)  # the map too, when the loops moved the trajectory

    def close(self, abort: bool = False) -> None:
        """Stop the reader and the mapper (thread or process) and delete the keyframes' spill file (it can hold
        gigabytes; the spilled images are then gone); ``abort`` (a second Ctrl-C) ends a mapping call in progress at
        its next iteration instead of waiting for it. Safe to call twice."""
        self.frames.close()
        if self.loops is not None:
            self.loops.close()
        if self.mapper is not None:
            self.mapper.close(abort=abort)
        self.keyframes.close()

    def run(self, progress: bool = True, observers: Sequence[Observer] = (), start: int | None = None) -> RunState:
        """Process the selected frames from ``start`` (default: where the state left off), with a progress bar
        (frame, live ATE, frame time) and the observers' ``on_frame`` after each one. After the last frame the
        mapper is drained (:meth:`finish`); a loop ended by an observer's :meth:`~Observer.stop_requested` or an
        exception leaves the pending mapping calls queued, as the schedule has them."""
        from tqdm import tqdm

        start = len(self.state.est) if start is None else start
        bar = tqdm(disable=not progress, unit="frame", dynamic_ncols=True,
                   desc=f"lrslam [{self.cfg.representation}]", initial=start, total=len(self.indices))
        try:
            k = start
            while True:  # not a range: a real-time replay passes over frames as it goes, a live camera adds them
                more, arrived = take_next(self, k)
                if not more:
                    break
                bar.total = len(self.indices)
                t0 = time.perf_counter()
                rec = self.step(k)
                note_latency(self, arrived)
                if self.cfg.trim_memory_every and (k + 1) % self.cfg.trim_memory_every == 0:
                    release_freed_memory()  # bounds the heap's fragmentation on long runs (slam.engine.runtime)
                rec.dt = time.perf_counter() - t0
                self.state.frame_times.append(rec.dt)
                rec.ate_m = live_ate(self.state.est, self.gt)
                view = self.view()
                for obs in observers:
                    obs.on_frame(view, rec)
                bar.update(1)
                bar.set_postfix_str(f"frame {self.indices[k]}  ATE {rec.ate_m * 100:.2f} cm  {rec.dt:.2f} s/frame")
                if (k + 1 < self._n_frames()) and any(obs.stop_requested() for obs in observers):
                    return self.state
                k += 1
        finally:
            bar.close()
        self.finish(progress)
        return self.state

    # ----------------------------------------------------------------------------------------------- the run
    def view(self) -> RunView:
        """A read-only view of the run for outputs, checkpoints, meshing and observers."""
        return view_of(self)

    def state_dict(self) -> dict:
        """The loop's state (:func:`slam.engine.system_state.system_state`): plain tensors and numbers."""
        return system_state(self)

    def load_state_dict(self, run: dict, scene: dict) -> None:
        """Put this freshly built system (same config and data) into a :meth:`state_dict`'s state with the mapper's
        map ``scene`` (:func:`slam.engine.system_state.load_system_state`, which says what it refuses)."""
        load_system_state(self, run, scene)
