"""One mapping call as both places that run it in the background do it, the mapper thread
(:mod:`slam.engine.map_worker`) and the mapping process (:mod:`slam.engine.map_child`): the call, its keyframe, the
map it left and the wall time of all of it, so the two measure the same thing."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import torch

from slam.engine import mapper

__all__ = ["MapJob", "run_map_call"]


@dataclass
class MapJob:
    """One mapping call: frame position ``k``, its images ``[H, W, 3]`` / ``[H, W]`` on the device, its tracked
    pose ``[7]``, whether it is the first-frame warm-up, whether it becomes a keyframe afterwards, and its iterations
    (0: ``mapping.iters``; the schedule's ``need_gap_iters`` for a routine refresh)."""

    k: int
    color: torch.Tensor
    depth: torch.Tensor
    pose: torch.Tensor
    first: bool
    keyframe: bool
    iters: int = 0


def run_map_call(job: MapJob, scene, keyframes, cfg, intrinsics, generator: torch.Generator, moments, *,
                 device=None, should_stop=None, snapshot: Callable[[dict], dict] | None = None):
    """Run ``job`` on ``scene`` (:func:`slam.engine.mapper.map_frame`, with its images and pose moved to ``device``
    when given), keep its frame in ``keyframes`` (:func:`slam.engine.mapper.keep_keyframe`, from the job's own
    images), then take the map the call left as ``snapshot(scene.state_dict())`` (None: no snapshot).

    Returns:
        ``(result, seconds, snapshot, snapshot_seconds)``: the :class:`slam.engine.mapper.MapResult`, the wall
        seconds of the whole call (the snapshot included), the snapshot (or None) and the seconds it took alone.
    """
    def to(t: torch.Tensor) -> torch.Tensor:
        return t if device is None else t.to(device)

    t0 = time.perf_counter()
    # through the module, at call time: tests replace mapper.map_frame (a faulty call, a probe of the map it left)
    res = mapper.map_frame(scene, job.k, to(job.color), to(job.depth), to(job.pose), intrinsics, keyframes, cfg,
                           generator, first=job.first, should_stop=should_stop, moments=moments, iters=job.iters)
    mapper.keep_keyframe(keyframes, job.k, job.color, job.depth, job.pose, res, job.keyframe)
    snap, snap_s = None, 0.0
    if snapshot is not None:
        t1 = time.perf_counter()
        snap = snapshot(scene.state_dict())
        snap_s = time.perf_counter() - t1
    return res, time.perf_counter() - t0, snap, snap_s
