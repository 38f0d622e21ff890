"""Tracking a frame with recovery: re-tracking an implausible result from other starts, and relocalising against
keyframes after a run of frames the tracker could not trust (the depth-ICP start: :mod:`slam.engine.icp_start`).

* :func:`recover` checks a tracking result with the :class:`slam.engine.tracking_guard.TrackingGuard` and, when it is
  implausible, tracks again from several starts and keeps the plausible candidate with the lowest loss on one
  common set of pixels.
* :func:`relocalise` runs once ``tracking.relocalize_after`` frames in a row were not trusted: it registers the
  frame's depth against the keyframes nearest the last trusted pose (ICP with a wide capture range, started at the
  keyframe's pose and at the prediction), tracks from each registration and from the prediction, and accepts a
  candidate whose loss passes the check against the history from before the gap, or one that depth confirms (it
  stayed within a few centimetres and degrees of its ICP registration: a camera that turned into space the map
  does not cover yet renders a high loss at the right pose). The caller then re-seeds the guard's history from the
  recovered frame, so the camera is let back in.

Everything here is deterministic for a seed: the draws come from the tracker's generator, and the keyframes are
read only after the mapper is idle (:meth:`slam.engine.map_worker.MapWorker.wait_idle`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from slam.core.odometry import icp_relative_pose
from slam.core.pose import matrix_to_pose, pose_distance, pose_to_matrix
from slam.core.camera import sample_pixels
from slam.engine.icp_start import screen_starts, turned
from slam.engine.tracker import TrackResult, evaluate_pose, track_frame
from slam.engine.tracking_guard import TrackingGuard, motion

# ICP for relocalisation: a keyframe can be tens of centimetres and degrees away, so the coarse level accepts
# correspondences up to 30 cm, both levels run more steps than the frame-to-frame start, and 15 % of the points
# may suffice (after a 28 degree turn only a quarter of the view still overlaps a keyframe, registered to 7 mm)
RELOC_ICP = {"iters": (20, 10), "max_dist": (0.30, 0.05), "min_inliers": 0.15}
# a tracked pose this close to its ICP registration against a keyframe is confirmed by depth alone
CONFIRM_M, CONFIRM_DEG = 0.05, 5.0


@dataclass
class TrackInput:
    """What tracking one frame needs: the map it tracks against, the frame's ``color`` ``[H, W, 3]`` and
    ``depth`` ``[H, W]`` (metres, on the scene's device), the working-image ``intr``, the run's ``cfg``, the
    tracker's ``gen`` and the ``guard``."""

    scene: object
    color: torch.Tensor
    depth: torch.Tensor
    intr: object
    cfg: object
    gen: torch.Generator
    guard: TrackingGuard


def _common_pixels(inp: TrackInput) -> tuple[torch.Tensor, torch.Tensor]:
    """The pixels candidates are compared on (drawn before the candidates are tracked: the draw order is part of
    what a seed repeats)."""
    H, W = inp.depth.shape
    return sample_pixels(H, W, 2 * inp.cfg.tracking.pixels, *inp.cfg.tracking.ignore_edge, generator=inp.gen)


def _best_on_common_pixels(inp: TrackInput, cands: list[tuple[str, TrackResult]], plausible: Callable, v, u):
    """The plausible candidate with the lowest loss on the pixels ``(v, u)`` (no jitter), or None."""
    cfg = inp.cfg
    scored = []
    for name, r in cands:
        if not plausible(r):
            continue
        loss, _ = evaluate_pose(inp.scene, inp.color, inp.depth, inp.intr, r.pose, cfg, v, u)
        scored.append((loss, name, r))
    if not scored:
        return None
    _, name, best = min(scored, key=lambda c: c[0])
    return name, best


def retry_iters(cfg) -> int:
    """The budget of one recovery or relocalisation attempt: twice a tracking call's, in the tracker's own unit
    (Adam: ``tracking.iters`` steps; Gauss-Newton: ``tracking.gn_iters`` loss evaluations a round)."""
    tc = cfg.tracking
    return 2 * (tc.gn_iters if tc.optimizer == "gauss_newton" else tc.iters)


def retry_config(cfg):
    """The config of a recovery attempt: ``cfg``, with ``tracking.recovery_optimizer: adam`` the Adam tracker (a
    real-time run, ``data.realtime`` as ``--realtime`` and ``lrslam live`` set it: ``realtime_recovery_optimizer``)."""
    import dataclasses

    tc = cfg.tracking
    choice = tc.realtime_recovery_optimizer if cfg.data.realtime else tc.recovery_optimizer
    if choice == "same" or tc.optimizer == "adam":
        return cfg
    return dataclasses.replace(cfg, tracking=dataclasses.replace(cfg.tracking, optimizer="adam"))


def recover(inp: TrackInput, res: TrackResult, prev: torch.Tensor, dt: float, starts: dict,
            prediction: torch.Tensor, event: Callable) -> tuple[TrackResult, bool, str | None]:
    """Check a tracking result; on an implausible one, track again from each of ``starts`` (name -> ``[7]``
    pose) with twice the iterations and keep the best plausible candidate. With none plausible the frame is lost:
    its pose is the ``prediction``.

    Args:
        prev: ``[7]`` pose of the last trusted frame; ``dt``: seconds since it (the motion checks).
        event: ``event(what, **extra)`` records a recovery (a log line and an entry in ``metrics.json``).

    Returns:
        ``(result, trusted, lost)``: ``lost`` is what to report when the frame stays lost (None when trusted);
        the caller reports it, unless relocalisation (:func:`relocalise`) then finds the pose.
    """
    cfg, guard = inp.cfg, inp.guard
    why = guard.reasons(res.loss, res.inliers, prev, res.pose, dt)
    if not why:
        guard.accept(res.loss)
        return res, True, None
    if not cfg.tracking.recovery:
        res.pose = prediction.clone()
        return res, False, f"tracking lost ({'; '.join(why)}): predicted pose kept"
    v, u = _common_pixels(inp)
    cands = [("first attempt", res)]
    retry_cfg = retry_config(cfg)
    for name, start in starts.items():
        r = track_frame(inp.scene, inp.color, inp.depth, inp.intr, start, retry_cfg, inp.gen,
                        iters=retry_iters(retry_cfg), patience=0)
        if r.ok:
            cands.append((name, r))
    found = _best_on_common_pixels(inp, cands, lambda r: not guard.reasons(r.loss, r.inliers, prev, r.pose, dt),
                                   v, u)
    if found is not None:
        name, best = found
        best.iters = sum(r.iters for _, r in cands)
        guard.accept(best.loss)
        event(f"tracking implausible ({'; '.join(why)}); recovered by tracking again from the {name}",
              recovered=True)
        return best, True, None
    # a pose no check accepts is worse than the motion model's guess: keep the prediction, do not map
    res.pose = prediction.clone()
    res.iters = sum(r.iters for _, r in cands)
    return res, False, (f"tracking lost ({'; '.join(why)}); {len(cands) - 1} recovery attempts failed: "
                        "predicted pose kept")


def nearest_keyframes(keyframes: list, anchor: torch.Tensor, n: int) -> list:
    """The ``n`` keyframes whose pose is closest to ``anchor`` ``[7]`` (:func:`slam.core.pose.pose_distance`, the
    keyframe store's redundancy measure), nearest first."""
    at = pose_to_matrix(anchor.double())
    return sorted(keyframes, key=lambda kf: pose_distance(at, pose_to_matrix(kf.pose.double())))[:n]


def _icp_against(kf, inp: TrackInput, guesses: list, keep: int = 3) -> torch.Tensor | None:
    """The best converged ICP registration of the frame against keyframe ``kf`` from ``guesses`` (``[7]`` poses),
    as a ``[7]`` pose; None when none converges. Every guess is first screened by a few steps at the coarse level
    alone (cheap); the ``keep`` with the most correspondences are then registered in full."""
    kf_depth = kf.metres().to(inp.depth.device)
    ref = pose_to_matrix(kf.pose).double()
    starts = [torch.linalg.solve(ref, pose_to_matrix(guess).double()) for guess in guesses]
    best = None
    for rel in screen_starts(kf_depth, inp.depth, inp.intr, starts, 0.30, keep,
                             smooth=inp.cfg.tracking.icp_normals):
        res = icp_relative_pose(kf_depth, inp.depth, inp.intr, init=rel, smooth=inp.cfg.tracking.icp_normals,
                                **RELOC_ICP)
        if res.ok and (best is None or res.rmse_m < best[0]):
            best = (res.rmse_m, matrix_to_pose((ref @ res.relative.double()).float()))
    return None if best is None else best[1]


def relocalise(inp: TrackInput, keyframes: list, anchor: torch.Tensor, dt: float, prediction: torch.Tensor,
               positions: Callable[[int], int]) -> tuple[TrackResult | None, str]:
    """Find the pose of a frame after a run of untrusted ones, against the keyframes nearest ``anchor``.

    Candidates: tracking from the ``prediction`` and from the ICP registration against each keyframe (started
    at the keyframe's pose and at the prediction). One is accepted when it passes the guard's inlier and motion
    checks (against ``anchor`` over ``dt`` seconds) and either its loss passes the check against the history from
    before the gap, or it is geometrically confirmed: registered against a keyframe by ICP and tracked to within
    :data:`CONFIRM_M` / :data:`CONFIRM_DEG` of that registration (new space the map does not cover yet renders a
    high loss at the right pose; a pose no depth confirms must not write the map). The lowest loss on common pixels
    wins.

    Args:
        keyframes: the run's :class:`slam.engine.keyframes.Keyframe` list (read after the mapper is idle).
        anchor: ``[7]`` pose of the last trusted frame; ``dt``: seconds since it.
        prediction: ``[7]`` the motion model's pose for the frame.
        positions: dataset frame number of a keyframe's position (for the event text).

    Returns:
        ``(result or None, the start it came from)``; the result's ``iters`` counts every tracking iteration
        spent on the candidates.
    """
    cfg, guard = inp.cfg, inp.guard
    starts = {"prediction": (prediction, None)}
    for kf in nearest_keyframes(keyframes, anchor, cfg.tracking.relocalize_keyframes):
        pose = _icp_against(kf, inp, [kf.pose, prediction, *turned(kf.pose)])
        if pose is not None:
            starts[f"ICP against the keyframe of frame {positions(kf.index)}"] = (pose, pose)
    v, u = _common_pixels(inp)
    cands, confirmed = [], {}
    retry_cfg = retry_config(cfg)
    for name, (start, registered) in starts.items():
        r = track_frame(inp.scene, inp.color, inp.depth, inp.intr, start, retry_cfg, inp.gen,
                        iters=retry_iters(retry_cfg), patience=0)
        if r.ok:
            cands.append((name, r))
            if registered is not None:
                d, deg = motion(registered, r.pose)
                confirmed[id(r)] = d <= CONFIRM_M and deg <= CONFIRM_DEG
    spent = sum(r.iters for _, r in cands)

    def acceptable(r) -> bool:
        if guard.reasons(r.loss, r.inliers, anchor, r.pose, dt, use_history=False):
            return False
        return confirmed.get(id(r), False) or not guard.reasons(r.loss, r.inliers, None, r.pose, dt)

    found = _best_on_common_pixels(inp, cands, acceptable, v, u)
    if found is None:
        return None, ""
    name, best = found
    best.iters = spent
    return best, name
