"""Where mapping runs: inline after each mapped frame (sequential), or on a worker thread beside the tracker
(parallel), with one schedule that makes both deterministic for a seed.

The schedule: a mapping call for frame ``m`` is submitted right after ``m`` is tracked; the tracker tracks frame
``j`` against the map exactly as the call of the latest mapped frame ``m <= j - lag`` left it, and only then
applies that call's results (its BA-refined pose of ``m``). Sequential mode is ``lag = 1``, run inline: every
frame is tracked against the map of the frame before it (ESLAM's effective behaviour). Parallel mode uses
``lag = max(every_frame, 2)``: the call of frame ``m`` runs while frames ``m + 1 ... m + lag - 1`` are tracked
against the previous map, and the tracker waits for it only at ``m + lag`` (the first call, the warm-up, is
always waited for). What the tracker sees is fixed by
the frame numbers, never by timing, so a parallel run repeats exactly too. A real-time run (``data.realtime`` or a
live camera, whose frames are taken by timing anyway) uses ``free`` mode by default (``mapping.realtime_sync``): the
tracker takes whichever calls have finished and never waits after the warm-up, and a frame is mapped only when no
call is running (:meth:`MapWorker.declines`), so the frames a busy mapper would have made it wait for are tracked.
With ``mapping.realtime_warmup: odometry`` it does not wait for the warm-up either: the loop calls :meth:`sync` once
:meth:`busy` says it would not wait, tracking the frames meanwhile by depth odometry (``track_by_odometry``).

The tracker never sees a half-written map: in parallel mode it tracks on its own copy of the scene, which is
overwritten only from a snapshot the mapper took at the end of a call (a ``state_dict`` copy, a few MB), while
the mapper thread is already on to the next call or idle. Only the worker touches ``scene`` and the keyframes
while a call runs; anything else that reads them (a checkpoint, a preview mesh) first waits with
:meth:`MapWorker.wait_idle`. So does a growth of the scene box (:meth:`MapWorker.grow`), which grows the mapper's
map, the tracker's copy and the maps pending calls left by the same samples, so the schedule is kept through it.

With ``mapper_process: true`` the calls run in a child process instead of a thread (:mod:`slam.engine.map_process`):
the same schedule and results, and ``scene`` and the keyframes here become mirrors the worker brings up to date as
each call's result arrives (the map it left, its keyframe and BA poses, the mapping random stream).
"""

from __future__ import annotations

import concurrent.futures
import copy
import threading
import time
from dataclasses import dataclass

import torch

from slam.engine.map_call import MapJob, run_map_call
from slam.engine.map_process import MapProcess
from slam.engine.wire import unpack_state
from slam.engine.mapper import MapMoments, MapResult, keep_keyframe
from slam.model.box_resize import ScenePads, apply_growth, load_scene_state, pad_state, plan_growth


@dataclass
class MapDone:
    """A finished call: the job, the mapper's result, wall seconds, and (parallel mode) the map it left."""

    job: MapJob
    result: MapResult
    seconds: float
    snapshot: dict | None = None


def _finished(call) -> bool:
    """Whether a queued call (a :class:`MapDone`, a thread's future or the mapping process's call) has finished."""
    return isinstance(call, MapDone) or call.done()


class MapWorker:
    """Runs mapping calls on ``scene`` (the map every output is written from) and keeps ``track_scene`` (what
    the tracker reads) in step with it by the schedule above.

    Args:
        scene: the :class:`slam.model.scene.SceneModel` mapping optimises.
        keyframes: the :class:`slam.engine.keyframes.KeyframeStore` (touched only by mapping calls).
        cfg, intrinsics: the run's config and working-image intrinsics.
        generator: CPU generator for the mapper's pixel and window draws.
        parallel: run calls beside the tracker (else inline), on a thread or (``cfg.mapper_process``) a process.
        rehearsal: ``(color, depth, pose)`` of a frame the child process rehearses its calls on before
            :meth:`ready` returns (``preload_kernels``, :mod:`slam.engine.rehearsal`); None: no rehearsal.
        free: (parallel only) the tracker never waits after the warm-up, and a call is declined while one runs
            (:meth:`declines`): a real-time run's ``mapping.realtime_sync: free``, see below.
    """

    def __init__(self, scene, keyframes, cfg, intrinsics, generator: torch.Generator, parallel: bool,
                 rehearsal: tuple | None = None, free: bool = False):
        self.scene = scene
        self.keyframes = keyframes
        self.cfg = cfg
        self.intr = intrinsics
        self.gen = generator
        self.parallel = parallel
        self.lag = max(cfg.mapping.every_frame, 2) if parallel else 1
        self.free = free and parallel
        self.declined = 0  # calls declined because one was running (free)
        self.track_scene = copy.deepcopy(scene) if parallel else scene
        self.process = MapProcess(cfg, intrinsics, scene.aabb.device, self._arrived) if (
            parallel and cfg.mapper_process) else None
        if self.process is not None:
            self.process.spawn(None if rehearsal is None else (scene.aabb.detach().cpu(),
                                                                *(t.detach().cpu() for t in rehearsal)))
        self._pool = (concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="lrslam-map")
                      if parallel and self.process is None else None)
        self._queue: list[tuple[int, concurrent.futures.Future | MapDone]] = []
        self.applied = 0  # calls whose results the tracker took (sync)
        self._abort = threading.Event()  # set by close(abort=True): a call in progress stops at its next iteration
        self.wait_s = 0.0  # time the tracker spent waiting for the mapper
        self.snapshot_s = 0.0  # time spent taking and loading snapshots
        self.map_s = 0.0  # wall time of the mapping calls themselves (wherever they ran)
        self.calls = 0
        self.moments = MapMoments()  # the map's Adam state between calls (mapping.optimizer_state: persistent)

    def ready(self) -> None:
        """Wait until the mapper process (if any) has started and rehearsed its calls (``rehearsal``)."""
        if self.process is not None:
            self.process.ready()

    # ---------------------------------------------------------------------------------------------- calls
    def _run(self, job: MapJob) -> MapDone:
        copy_state = (lambda state: {name: t.detach().clone() for name, t in state.items()}) if self.parallel else None
        res, seconds, snap, snap_s = run_map_call(job, self.scene, self.keyframes, self.cfg, self.intr, self.gen,
                                                  self.moments, should_stop=self._abort.is_set, snapshot=copy_state)
        self.snapshot_s += snap_s
        self.map_s += seconds
        self.calls += 1
        return MapDone(job, res, seconds, snap)

    def _arrived(self, job: MapJob, reply: dict) -> MapDone:
        """A call of the child process finished (in order): make the mirrors what the child's are now."""
        t0 = time.perf_counter()
        res = reply["result"]
        # the child dropped a keyframe (mapping.max_keyframes) by its BA-refined poses: take its choice, not ours
        keep_keyframe(self.keyframes, job.k, job.color, job.depth, job.pose, res, job.keyframe, drop=False)
        self.keyframes.follow(reply["indices"], reply["poses"])
        self.gen.set_state(reply["gen"])
        snapshot = unpack_state(reply["snapshot"])
        with torch.no_grad():
            self.scene.load_state_dict(snapshot)
        self.snapshot_s += time.perf_counter() - t0
        self.map_s += reply["seconds"]
        self.calls += 1
        return MapDone(job, res, reply["seconds"], snapshot)

    def submit(self, job: MapJob) -> None:
        """Queue a call (run it now, in sequential mode)."""
        if self.process is not None:
            if not self.process.started:
                self.process.start(self.scene, self.keyframes, self.gen, self.moments)
            self._queue.append((job.k, self.process.submit(job)))
        elif self.parallel:
            self._queue.append((job.k, self._pool.submit(self._run, job)))
        else:
            self._queue.append((job.k, self._run(job)))

    def _collect(self, upto: int | None) -> list[MapDone]:
        ready = [(k, f) for k, f in self._queue if upto is None or k <= upto]
        self._queue = [(k, f) for k, f in self._queue if not (upto is None or k <= upto)]
        out = []
        for _, f in ready:
            if isinstance(f, MapDone):
                out.append(f)
            else:
                t0 = time.perf_counter()
                out.append(f.result())
                self.wait_s += time.perf_counter() - t0
        if self.parallel and out:
            t0 = time.perf_counter()
            with torch.no_grad():
                self.track_scene.load_state_dict(out[-1].snapshot)
            self.snapshot_s += time.perf_counter() - t0
            for d in out:
                d.snapshot = None
        return out

    def _upto(self, j: int) -> int:
        upto = self._newest_finished() if self.free else j - self.lag
        return max(upto, self._queue[0][0]) if not self.applied and self._queue else upto

    def _newest_finished(self) -> int:
        """The frame of the newest queued call that has finished with every call before it (-1: none)."""
        upto = -1
        for k, f in self._queue:
            if not _finished(f):
                break
            upto = k
        return upto

    def idle(self) -> bool:
        """Whether no call is running (those queued have all finished)."""
        return all(_finished(f) for _, f in self._queue)

    def drained(self) -> bool:
        """Whether every call submitted has been applied (:meth:`sync`): idle, no finished result waiting."""
        return not self._queue

    def declines(self, first: bool) -> bool:
        """Whether a call submitted now is not made (counted in ``declined``): free mode, not the warm-up, and a call
        is still running. A camera does not wait, so a real-time run maps the newest frame that wants mapping once
        the mapper is free instead of queueing calls the tracker would wait for; what is mapped then depends on
        timing, as the frames a real-time run takes do (:mod:`slam.engine.realtime`)."""
        if not self.free or first or self.idle():
            return False
        self.declined += 1
        return True

    def busy(self, j: int) -> bool:
        """Whether :meth:`sync` of frame ``j`` would wait now: a call it finishes is still running."""
        upto = self._upto(j)
        return any(not _finished(f) for k, f in self._queue if k <= upto)

    def sync(self, j: int, idle=None) -> list[MapDone]:
        """Before tracking frame ``j``: finish the calls of frames ``<= j - lag`` (waiting if needed), make the
        tracker's map the one the last of them left, and return them in order so the loop can apply their
        results. The first call (the warm-up) is always waited for: nothing is tracked against an empty map.
        ``idle(j, busy)``: work to do first while ``busy()`` says the wait has not ended (reading frames ahead,
        :meth:`slam.engine.frames.FrameSource.read_while`); it cannot change what the calls compute."""
        if idle is not None:
            idle(j, lambda: self.busy(j))
        out = self._collect(self._upto(j))
        self.applied += len(out)
        return out

    def drain(self) -> list[MapDone]:
        """Finish every queued call; the tracker's map then equals the mapper's. Returns the calls finished."""
        out = self._collect(None)
        if self.parallel:
            with torch.no_grad():
                self.track_scene.load_state_dict(self.scene.state_dict())
        return out

    def wait_idle(self) -> None:
        """Wait until no call is running (their results stay queued for the schedule): before anything outside the
        worker reads ``scene`` or the keyframes (a checkpoint, a preview mesh)."""
        for _, f in self._queue:
            if not isinstance(f, MapDone):
                t0 = time.perf_counter()
                f.result()
                self.wait_s += time.perf_counter() - t0

    def grow(self, lower, upper) -> ScenePads:
        """Grow the map's box by ``lower`` / ``upper`` metres per axis (:mod:`slam.model.box_resize`), between calls: it
        waits for the call running, then grows the mapper's scene, the tracker's copy and the maps the pending
        calls left by the same samples, so the schedule goes on handing the tracker the maps it names, grown."""
        self.wait_idle()
        pads = plan_growth(self.scene, lower, upper)
        apply_growth(self.scene, pads)
        self.moments.reset()  # moments of the old factors' shapes: the next call starts a fresh Adam
        if self.process is not None and self.process.started:
            self.process.grow(pads)
        if self.parallel:
            apply_growth(self.track_scene, pads)
            for _, item in self._queue:
                done = item if isinstance(item, MapDone) else item.result()
                if done.snapshot is not None:
                    done.snapshot = pad_state(done.snapshot, pads)
        return pads

    def state_dict(self) -> dict:
        """``{"pending", "applied_any", "track_scene", "moments"}``: the calls not yet applied (waited for, with their
        results and, in parallel mode, the map each left), whether any was applied, the tracker's copy of the map
        (parallel mode; None inline, where it is the scene) and the map's carried Adam state (None if none). Plain
        tensors and numbers."""
        pending = []
        for _, item in self._queue:
            done = item if isinstance(item, MapDone) else item.result()
            pending.append({"k": done.job.k, "pose": done.job.pose.cpu(), "first": done.job.first,
                            "keyframe": done.job.keyframe, "seconds": done.seconds,
                            "result": {"pose": done.result.pose.cpu(), "window": list(done.result.window),
                                       "loss": float(done.result.loss), "ok": bool(done.result.ok),
                                       "skipped": int(done.result.skipped)},
                            "snapshot": done.snapshot})
        track = ({k: v.detach().cpu() for k, v in self.track_scene.state_dict().items()} if self.parallel else None)
        if self.process is not None and self.process.started:  # the child holds them (sent on request only)
            self.moments.state = self.process.moments()
        return {"pending": pending, "applied_any": bool(self.applied), "track_scene": track,
                "moments": self.moments.cpu_state()}

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict`: the pending calls are queued as finished (their images are not needed:
        only their results are applied).

        Raises:
            RuntimeError: the tracker's map or the carried moments do not fit this scene (another config)."""
        if state["track_scene"] is not None:
            load_scene_state(self.track_scene, state["track_scene"])
        self.applied = int(bool(state["applied_any"]))  # the count is not kept: whether any was
        self.moments = MapMoments(state.get("moments"))  # a checkpoint from before the key: none carried
        self.moments.check(self.scene)
        self._queue = []
        for p in state["pending"]:
            job = MapJob(p["k"], None, None, p["pose"], p["first"], p["keyframe"])
            r = p["result"]
            res = MapResult(r["pose"], r["window"], r["loss"], r["ok"], r["skipped"])
            self._queue.append((p["k"], MapDone(job, res, p["seconds"], p["snapshot"])))
        if self.process is not None and self.process.started:  # its replica is another map: the next call starts anew
            self.process.close()  # (a child spawned but not given a map yet is kept, its imports and rehearsal done)

    def close(self, abort: bool = False) -> None:
        """Shut the worker down; ``abort``: end a call in progress at its next iteration and do not wait for it
        (its work is lost; the map is then unusable, so nothing may be saved from it afterwards)."""
        if self.process is not None:
            self.process.close(abort=abort)
        if self._pool is not None:
            if abort:
                self._abort.set()
            self._pool.shutdown(wait=not abort, cancel_futures=True)
            self._pool = None
