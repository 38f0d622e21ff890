"""Tracking a frame with recovery: the depth-ICP start, re-tracking an implausible result from other starts, and
relocalising against keyframes after a run of frames the tracker could not trust.

* :func:`icp_start` chains the ICP motion onto the pose of the frame whose depth it registers against (the last
  trusted frame with depth), never onto the previous frame's pose: after a frame without depth, an unreadable
  frame or a lost one those are different frames, and the start would carry the gap's motion twice.
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

from slam.core.odometry import hold_unobserved, icp_relative_pose, pyramid, unobserved_directions
from slam.core.pose import matrix_to_pose, pose_distance, pose_to_matrix
from slam.core.camera import sample_pixels
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


def icp_start(ref_pose: torch.Tensor, ref_depth: torch.Tensor, guess: torch.Tensor, depth: torch.Tensor,
              intr, hold_pose: torch.Tensor | None = None, hold: float = 0.0, **icp) -> tuple[torch.Tensor, bool]:
    """The start pose of a frame from depth ICP against a reference frame.

    Args:
        ref_pose: ``[7]`` camera-to-world pose of the reference frame (the frame ``ref_depth`` was taken from).
        ref_depth, depth: ``[H, W]`` metres (0 invalid) of the reference and the current frame.
        guess: ``[7]`` the current frame's predicted pose; ICP starts at the motion it implies.
        intr: working-image intrinsics.
        hold_pose, hold: ``tracking.icp_hold`` (ours): in the directions the reference image's geometry does not
            observe (a single plane in view; :func:`slam.core.odometry.unobserved_directions` with ratio ``hold``),
            the start is ``hold_pose``'s ``[7]`` (the previous pose), not the guess's (0: off).
        icp: more :func:`slam.core.odometry.icp_relative_pose` arguments.

    Returns:
        ``(pose [7], converged)``: ``ref_pose`` times the registered motion, or ``guess`` when ICP does not converge.
    """
    ref = pose_to_matrix(ref_pose).double()
    rel0 = torch.linalg.solve(ref, pose_to_matrix(guess).double())
    res = icp_relative_pose(ref_depth, depth, intr, init=rel0, **icp)
    if not res.ok:
        return guess, False
    rel = res.relative.double()
    if hold > 0 and hold_pose is not None:
        rel = hold_unobserved(rel, torch.linalg.solve(ref, pose_to_matrix(hold_pose).double()),
                              unobserved_directions(ref_depth, intr, hold))
    return matrix_to_pose((ref @ rel).float()), True


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
    """The config of a recovery attempt: ``cfg``, with ``tracking.recovery_optimizer: adam`` the Adam tracker."""
    import dataclasses

    if cfg.tracking.recovery_optimizer == "same" or cfg.tracking.optimizer == "adam":
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


def turned(pose: torch.Tensor, degrees: tuple[float, ...] = (-32.0, -24.0, -16.0, -8.0, 8.0, 16.0, 24.0, 32.0),
           axes: tuple[int, ...] = (0, 1, 2)) -> list[torch.Tensor]:
    """``pose`` ``[7]`` turned about each of its camera's ``axes`` (0: x, pitch; 1: y, yaw; 2: z, roll) by each of
    ``degrees``: ICP starts for a camera that rotated while nothing was seen (projective association captures only
    a few degrees; a hand-held camera turns 30 degrees in half a second)."""
    out = []
    T = pose_to_matrix(pose.double())
    for axis in axes:
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        for deg in degrees:
            a = torch.deg2rad(torch.tensor(deg, dtype=torch.float64))
            R = torch.eye(4, dtype=torch.float64)
            R[i, i], R[i, j], R[j, i], R[j, j] = torch.cos(a), -torch.sin(a), torch.sin(a), torch.cos(a)
            out.append(matrix_to_pose((T @ R).float()))
    return out


def _icp_against(kf, inp: TrackInput, guesses: list, keep: int = 3) -> torch.Tensor | None:
    """The best converged ICP registration of the frame against keyframe ``kf`` from ``guesses`` (``[7]`` poses),
    as a ``[7]`` pose; None when none converges. Every guess is first screened by a few steps at the coarse level
    alone (cheap); the ``keep`` with the most correspondences are then registered in full."""
    kf_depth = kf.metres().to(inp.depth.device)
    ref = pose_to_matrix(kf.pose).double()
    coarse = pyramid(*inp.depth.shape)[0]
    screened = []
    for guess in guesses:
        rel0 = torch.linalg.solve(ref, pose_to_matrix(guess).double())
        res = icp_relative_pose(kf_depth, inp.depth, inp.intr, init=rel0, levels=(coarse,), iters=(6,),
                                max_dist=(0.30,), min_inliers=0.0, smooth=inp.cfg.tracking.icp_normals)
        screened.append((res.inliers if torch.isfinite(res.relative).all() else -1.0, len(screened), res.relative))
    best = None
    for _, _, rel in sorted(screened, key=lambda c: (-c[0], c[1]))[:keep]:
        res = icp_relative_pose(kf_depth, inp.depth, inp.intr, init=rel.double(), smooth=inp.cfg.tracking.icp_normals,
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
