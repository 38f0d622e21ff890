"""Tracking one frame the way the loop does: predict, start from depth ICP, track, check, recover, relocalise.

:func:`predict` gives the motion model's pose; :func:`track_without_depth` tracks a frame without valid depth on
its colour; :func:`track_by_odometry` a frame of a real-time run that arrives before the first map exists;
:func:`track_with_recovery` tracks from the ICP start (:func:`slam.engine.icp_start.icp_start`), checks the result
with the guard, re-tracks an implausible one (:func:`slam.engine.recovery.recover`) and, after
``tracking.relocalize_after`` untrusted frames in a row, relocalises against the keyframes
(:func:`slam.engine.recovery.relocalise`). It reads and updates only the
:class:`slam.engine.state.RunState` it is handed (``reloc_tried_at``) and the guard (its history restarts after a
relocalisation); everything it decides is an event.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable

import torch

from slam.core.pose import constant_velocity
from slam.engine.icp_start import icp_start
from slam.engine.recovery import TrackInput, recover, relocalise
from slam.engine.state import RunState
from slam.engine.tracker import TrackResult, track_frame, track_on_color
from slam.engine.tracking_guard import TrackingGuard

log = logging.getLogger("slam")


def predict(est: list, trusted: list, init: str) -> tuple[torch.Tensor, str]:
    """The pose ``[7]`` the next frame starts from before tracking, and what it is.

    Constant velocity over the last two poses of ``est`` (unless ``tracking.init`` is ``previous``) when both are
    trusted (``trusted`` holds a flag per pose), else the previous pose. A velocity is a measurement only between
    two trusted poses: across an untrusted one (a lost result, a prediction) or a jump back to a trusted pose
    (relocalisation, recovery from the last trusted pose) the difference of the last two poses is a correction,
    and extrapolating it frame after frame ran a fixed-box walk out to 28 km while it was lost (docs/robustness.md,
    "Tracking that knows when it is lost")."""
    if init != "previous" and len(est) >= 2 and trusted[-1] and trusted[-2]:
        return constant_velocity(est[-1], est[-2]), "constant-velocity pose"
    return est[-1].clone(), "previous pose"


@dataclass
class Timeline:
    """What tracking needs of the run beyond the frame: ``dt(k, j)`` seconds from position ``j`` to ``k``;
    ``keyframes()`` the keyframe list once the mapper is idle; ``frame_of(k)`` the dataset frame number of
    position ``k``; ``event(k, what, **extra)`` records an event."""

    dt: Callable[[int, int], float]
    keyframes: Callable[[], list]
    frame_of: Callable[[int], int]
    event: Callable[..., None]


def track_with_recovery(k: int, inp: TrackInput, st: RunState, pred: torch.Tensor, what: str,
                        run: Timeline) -> tuple[TrackResult, bool]:
    """Track frame position ``k`` (its images in ``inp``) from the ICP start or the prediction ``pred``; returns
    ``(result, trusted)``. An untrusted result's pose is still the best the loop has (it is recorded, not mapped)."""
    cfg = inp.cfg
    init = pred
    if cfg.tracking.init == "icp" and st.prev_depth is not None:
        # ICP registers against the last trusted frame with depth: chain its motion onto that frame's pose
        init, _ = icp_start(st.est[st.prev_depth_k], st.prev_depth, pred, inp.depth, inp.intr, hold_pose=st.est[-1],
                            hold=cfg.tracking.icp_hold, smooth=cfg.tracking.icp_normals, wide=cfg.tracking.icp_wide,
                            note=lambda what: run.event(k, what, wide_start=True))
    res = track_frame(inp.scene, inp.color, inp.depth, inp.intr, init, cfg, inp.gen)
    last = st.last_trusted()
    anchor, dt = (st.est[last], run.dt(k, last)) if last >= 0 else (st.est[-1], run.dt(k, max(k - 1, 0)))
    if not res.ok:
        res.pose, trusted, lost = pred, False, f"tracking failed ({res.message}): {what} used"
    else:
        starts = {"start": init, what: pred, "previous pose": st.est[-1]}
        if 0 <= last < k - 1:
            starts["last trusted pose"] = st.est[last]
        res, trusted, lost = recover(inp, res, anchor, dt, starts, pred, lambda m, **x: run.event(k, m, **x))
    if trusted:
        return res, True
    untrusted = k - 1 - last  # frames in a row before this one without a trusted pose
    n = cfg.tracking.relocalize_after
    if n and last >= 0 and untrusted >= n and (st.reloc_tried_at <= last or k - st.reloc_tried_at >= n):
        st.reloc_tried_at = k
        best, found = _relocalise(inp, run, anchor, dt, pred)
        if best is not None:
            run.event(k, f"{lost}; relocalised from the {found} after {untrusted} untrusted frames "
                         "(loss history restarted)", relocalised=True)
            best.iters += res.iters
            return best, True
        lost += f"; relocalisation after {untrusted} untrusted frames found no plausible pose"
    run.event(k, f"{lost}, frame not mapped", lost=True)
    return res, False


def track_by_odometry(k: int, depth: torch.Tensor | None, intr, st: RunState, pred: torch.Tensor, what: str, cfg,
                      guard: TrackingGuard, run: Timeline) -> tuple[torch.Tensor, bool]:
    """Frame position ``k``'s pose while the first map is still being built (``mapping.realtime_warmup:
    odometry``): depth ICP (``depth`` ``[H, W]`` metres; None: the frame has no valid depth) against the last
    trusted frame with depth, started at the prediction ``pred``, its motion chained onto that frame's pose; no map
    is read. A frame without depth, a registration that does not converge or one that moves faster than the guard
    allows keeps the prediction, untrusted. A trusted result becomes the next frame's ICP reference
    (``st.prev_depth``); the frame is not mapped (the mapper is busy). Each frame's outcome is an event
    (``odometry``: whether its pose is the registration's; logged at INFO, as it happens to every frame of the
    warm-up).

    Returns:
        ``(pose [7], trusted)``.
    """
    frame = run.frame_of(k)
    if depth is None:
        run.event(k, f"no valid depth and no map yet: not tracked, {what} used", odometry=False)
        return pred, False
    tc, ref = cfg.tracking, int(st.prev_depth_k)
    pose, ok = icp_start(st.est[ref], st.prev_depth, pred, depth, intr, hold_pose=st.est[-1], hold=tc.icp_hold,
                         smooth=tc.icp_normals, wide=tc.icp_wide, note=lambda what: run.event(k, what, wide_start=True))
    why = [] if ok else ["depth ICP did not converge"]
    last = st.last_trusted()
    if ok and last >= 0:
        why = guard.reasons(0.0, 1.0, st.est[last], pose, run.dt(k, last), use_history=False)
    if why:
        what = f"first map not built yet, depth odometry not taken ({'; '.join(why)}): {what} used"
    else:
        what = f"first map not built yet: tracked by depth odometry against frame {run.frame_of(ref)}"
        st.prev_depth, st.prev_depth_k = depth, k
    log.info("frame %d: %s", frame, what)
    st.events.append({"frame": frame, "event": what, "odometry": not why})
    return (pred, False) if why else (pose, True)


def _relocalise(inp: TrackInput, run: Timeline, anchor: torch.Tensor, dt: float, pred: torch.Tensor):
    """Relocalise against the keyframes (read once the mapper is idle, so the same ones whatever the threads'
    timing); on success the guard's history restarts from the result. Returns ``(result or None, its start)``."""
    kfs = run.keyframes()
    if not kfs:
        return None, ""
    best, found = relocalise(inp, kfs, anchor, dt, pred, run.frame_of)
    if best is not None:
        inp.guard.reset(best.loss)
    return best, found


# a colour image whose standard deviation is below this has nothing to track on (a sensor that saw nothing)
MIN_CONTRAST = 1e-3


def track_without_depth(k: int, inp: TrackInput, st: RunState, pred: torch.Tensor, what: str,
                        run: Timeline) -> tuple[torch.Tensor, bool]:
    """Track frame position ``k``, which has no valid depth, on its colour from the prediction ``pred``
    (``tracking.without_depth: color``; :func:`slam.engine.tracker.track_on_color`).

    The colour pose is taken when its colour error (same rays, no jitter) is below the prediction's and the guard's
    motion checks pass against the last trusted frame; otherwise the prediction stays. Either way the frame stays
    untrusted (it is not mapped, and the motion model does not take a velocity across it), and an event says what
    happened (``color_tracked``; where colour tracking ran, ``color_loss``, ``color_iters`` and ``color_share``, the
    share of the pixels that see the map); the per-frame tracking records keep the depth tracking loss only, and
    ``frames.csv`` shows both, its ``tracked_on`` column saying which.

    Returns:
        ``(pose [7], whether colour tracking ran)``.
    """
    res, pose, happened = _color_pose(k, inp, st, pred, what, run)
    extra = {} if res is None else {"color_loss": res.loss if math.isfinite(res.loss) else None,  # JSON has no NaN
                                    "color_iters": res.iters, "color_share": res.inliers}
    run.event(k, f"no valid depth: {happened}", color_tracked=bool(res is not None and res.ok), **extra)
    return pose, res is not None


def _color_pose(k, inp: TrackInput, st: RunState, pred, what: str, run: Timeline):
    """``(result or None, pose [7], what happened)`` of :func:`track_without_depth`."""
    if inp.cfg.tracking.without_depth == "predict":
        return None, pred, f"not tracked, {what} used"
    if float(inp.color.std()) < MIN_CONTRAST:
        return None, pred, f"the colour image has no contrast either: not tracked, {what} used"
    res, start = track_on_color(inp.scene, inp.color, inp.intr, pred, inp.cfg, inp.gen)
    if not res.ok:
        return res, pred, f"colour tracking failed ({res.message}): {what} used"
    last = st.last_trusted()
    why = []
    if not res.loss < start:
        why.append(f"colour error {res.loss:.3g} not below the {what}'s {start:.3g}")
    if last >= 0:
        why += inp.guard.reasons(res.loss, 1.0, st.est[last], res.pose, run.dt(k, last), use_history=False)
    if why:
        res.ok = False
        return res, pred, f"colour tracking not taken ({'; '.join(why)}): {what} used"
    return res, res.pose, (f"tracked on colour from the {what} (colour error {start:.3g} -> {res.loss:.3g}, "
                           f"{res.iters} iterations, {100 * res.inliers:.0f} % of the pixels see the map)")
