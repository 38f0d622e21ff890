"""Loading the kernels before the first frame (``preload_kernels: true``): a throwaway mapping call and tracking call.

The fused kernels (numba on the CPU, Triton on CUDA) load from their caches at their first call, about 0.4 s for the
mapper's and 0.2-0.6 s for the tracker's at ``tum/fr1_rpy-cpu-fast``; without a preload that lands in the first
frames (frame 1 waits for the warm-up call, which loads the mapper's). A live system loads them while it starts, as
it imports its modules then, so the first frames are not late: here on the run's first readable frame, from its
starting pose, on a copy of the initial map, with a keyframe store, generators and a config of their own (two
mapping iterations instead of the warm-up's). Nothing of it is kept: the run's map, keyframes and random streams are
untouched, so its results are the same bit for bit (tested). ``metrics.json`` reports the time it took as
``preload_s``, apart from the frame times.
"""

from __future__ import annotations

import copy
import dataclasses
import logging

import torch

from slam.engine.keyframes import KeyframeStore
from slam.engine.mapper import keep_keyframe, map_frame
from slam.engine.icp_start import icp_start
from slam.engine.tracker import track_frame

__all__ = ["preload", "rehearse_mapping", "rehearse_tracking"]

log = logging.getLogger(__name__)


def rehearse_mapping(scene, cfg, intrinsics, color: torch.Tensor, depth: torch.Tensor, pose: torch.Tensor) -> None:
    """Two short mapping calls (a warm-up's, then a windowed one's) of the frame ``color`` ``[H, W, 3]`` / ``depth``
    ``[H, W]`` (on the scene's device) from ``pose`` ``[7]``, on a copy of ``scene``; everything they change is
    thrown away. A rehearsal that fails is logged, not raised: the kernels then load in the run's first calls, which
    report what is wrong."""
    try:
        _map_twice(copy.deepcopy(scene), cfg, intrinsics, color, depth, pose)
    except Exception as exc:  # noqa: BLE001 - only a preload; the run's own calls raise with context
        log.warning("kernel preload: the rehearsed mapping call failed (%s: %s)", type(exc).__name__, exc)


def _map_twice(scene, cfg, intrinsics, color, depth, pose) -> None:
    short = dataclasses.replace(cfg, mapping=dataclasses.replace(cfg.mapping, iters=2, iters_first=2))
    keyframes = KeyframeStore.for_mapping(short.mapping)
    gen = torch.Generator().manual_seed(0)
    for k, first in ((0, True), (1, False)):
        res = map_frame(scene, k, color, depth, pose, intrinsics, keyframes, short, gen, first=first)
        keep_keyframe(keyframes, k, color, depth, pose, res, True)


def rehearse_tracking(scene, cfg, intrinsics, color: torch.Tensor, depth: torch.Tensor, pose: torch.Tensor) -> None:
    """The ICP start (``tracking.init: icp``) and one tracking call of the frame against itself from ``pose`` ``[7]``,
    on a copy of ``scene``; the results are thrown away (a failure is logged, as in :func:`rehearse_mapping`)."""
    try:
        scene = copy.deepcopy(scene)
        if cfg.tracking.init == "icp":
            icp_start(pose, depth, pose, depth, intrinsics, hold_pose=pose, hold=cfg.tracking.icp_hold,
                      smooth=cfg.tracking.icp_normals)
        track_frame(scene, color, depth, intrinsics, pose, cfg, torch.Generator().manual_seed(0))
    except Exception as exc:  # noqa: BLE001
        log.warning("kernel preload: the rehearsed tracking call failed (%s: %s)", type(exc).__name__, exc)


def preload(scene, cfg, intrinsics, frame: tuple, mapper) -> None:
    """Before the first frame (``preload_kernels``): rehearse the tracking call and, unless the mapper runs in its
    own process (which rehearses its calls while this runs), the mapping call, on ``frame`` ``(color, depth,
    pose)``; then wait until ``mapper`` (a :class:`slam.engine.map_worker.MapWorker`) is ready."""
    if cfg.preload_kernels:
        rehearse_tracking(scene, cfg, intrinsics, *frame)
        if mapper.process is None:
            rehearse_mapping(scene, cfg, intrinsics, *frame)
    mapper.ready()
