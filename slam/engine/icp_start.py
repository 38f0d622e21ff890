"""The tracker's start: depth ICP of a frame against the last trusted frame with depth (``tracking.init: icp``).

* :func:`icp_start` chains the ICP motion onto the pose of the frame whose depth it registers against (the last
  trusted frame with depth), never onto the previous frame's pose: after a frame without depth, an unreadable
  frame or a lost one those are different frames, and the start would carry the gap's motion twice.
* With ``tracking.icp_wide`` a registration that matches few of the frame's points is tried again from wider
  starts (:func:`wider_registration`): the constant-velocity guess is the only start otherwise, and where the
  camera turns 10 degrees or more between the frames the tracker takes its error can be wider than projective
  ICP's basin.
* :func:`turned` makes starts for a camera that rotated (also relocalisation's, :mod:`slam.engine.recovery`).
"""

from __future__ import annotations

from typing import Callable

import torch

from slam.core.odometry import hold_unobserved, icp_relative_pose, pyramid, unobserved_directions
from slam.core.pose import matrix_to_pose, pose_to_matrix

# tracking.icp_wide's starts: the guess turned by these degrees about each camera axis. Projective ICP's basin can be
# narrower than the error of a constant-velocity guess where the camera turns 10 degrees or more between frames
# (the fast fr1_rpy window every 4th frame: a start 3.2 degrees off converged 10 degrees and 27 cm wrong, matching
# 42 % of the points, where the true pose matches 67 %; docs/robustness.md, "How far apart the frames can be")
WIDE_DEGREES = (-8.0, 8.0)
# a wider start replaces the registration from the guess only when it matches this share of the points more
WIDE_MARGIN = 0.05


def icp_start(ref_pose: torch.Tensor, ref_depth: torch.Tensor, guess: torch.Tensor, depth: torch.Tensor,
              intr, hold_pose: torch.Tensor | None = None, hold: float = 0.0, wide: float = 0.0,
              note: Callable[[str], None] | None = None, **icp) -> tuple[torch.Tensor, bool]:
    """The start pose of a frame from depth ICP against a reference frame.

    Args:
        ref_pose: ``[7]`` camera-to-world pose of the reference frame (the frame ``ref_depth`` was taken from).
        ref_depth, depth: ``[H, W]`` metres (0 invalid) of the reference and the current frame.
        guess: ``[7]`` the current frame's predicted pose; ICP starts at the motion it implies.
        intr: working-image intrinsics.
        hold_pose, hold: ``tracking.icp_hold`` (ours): in the directions the reference image's geometry does not
            observe (a single plane in view; :func:`slam.core.odometry.unobserved_directions` with ratio ``hold``),
            the start is ``hold_pose``'s ``[7]`` (the previous pose), not the guess's (0: off).
        wide: ``tracking.icp_wide`` (ours): a registration from the guess that matches fewer than this share of the
            points is tried again from wider starts (:func:`wider_registration`) and the one matching the most
            is kept (0: off); ``note`` is told when a wider start's registration is taken (an event).
        icp: more :func:`slam.core.odometry.icp_relative_pose` arguments.

    Returns:
        ``(pose [7], converged)``: ``ref_pose`` times the registered motion, or ``guess`` when ICP does not converge.
    """
    ref = pose_to_matrix(ref_pose).double()
    rel0 = torch.linalg.solve(ref, pose_to_matrix(guess).double())
    held = None if hold_pose is None else torch.linalg.solve(ref, pose_to_matrix(hold_pose).double())
    res = icp_relative_pose(ref_depth, depth, intr, init=rel0, **icp)
    if wide > 0 and res.inliers < wide:
        starts = [torch.linalg.solve(ref, pose_to_matrix(p).double()) for p in turned(guess, WIDE_DEGREES)]
        if held is not None:
            starts.append(held)
        wider = wider_registration(ref_depth, depth, intr, res, starts, **icp)
        if wider is not res and note is not None:
            note(f"depth ICP from the prediction matched {100 * res.inliers:.0f} % of the points, from a wider start "
                 f"{100 * wider.inliers:.0f} %: that start taken")
        res = wider
    if not res.ok:
        return guess, False
    rel = res.relative.double()
    if hold > 0 and held is not None:
        rel = hold_unobserved(rel, held, unobserved_directions(ref_depth, intr, hold))
    return matrix_to_pose((ref @ rel).float()), True


def wider_registration(ref_depth: torch.Tensor, depth: torch.Tensor, intr, first, starts: list, keep: int = 2,
                       **icp):
    """The registration of ``depth`` to ``ref_depth`` (``[H, W]`` metres) matching the most points: ``first`` (an
    :class:`slam.core.odometry.ICPResult`, the registration from the guess) or one from ``starts`` (``[4, 4]``
    relative poses in the reference camera's frame). Every start is screened by a few steps at the coarse level
    alone (cheap); the ``keep`` matching the most are registered in full (``icp``: the same arguments as
    ``first``'s), and one replaces ``first`` only where it converged and matches :data:`WIDE_MARGIN` more of the
    points (a wrong registration matches fewer: the surfaces it pairs do not meet)."""
    best = first
    for rel in screen_starts(ref_depth, depth, intr, starts, 0.10, keep, **_normals_of(icp)):
        r = icp_relative_pose(ref_depth, depth, intr, init=rel, **icp)
        if r.ok and r.inliers > (best.inliers if best.ok else 0.0) + WIDE_MARGIN:
            best = r
    return best


def _normals_of(icp: dict) -> dict:
    # the screen averages normals as the full registration does; where the caller left ``smooth`` to
    # icp_relative_pose's default, so does the screen
    return {"smooth": icp["smooth"]} if "smooth" in icp else {}


def screen_starts(ref_depth: torch.Tensor, depth: torch.Tensor, intr, starts: list, max_dist: float, keep: int,
                  **normals) -> list[torch.Tensor]:
    """The ``keep`` of ``starts`` (``[4, 4]`` relative poses in the reference camera's frame) whose registration
    matches the most points after a few steps at the coarse pyramid level alone (cheap; correspondences up to
    ``max_dist`` metres), as those screened ``[4, 4]`` float64 poses, the best first (ties: the earlier start).
    ``normals``: ``smooth`` for :func:`slam.core.odometry.icp_relative_pose` (its default when left out)."""
    coarse = pyramid(*depth.shape)[0]
    screened = []
    for i, rel0 in enumerate(starts):
        r = icp_relative_pose(ref_depth, depth, intr, init=rel0, levels=(coarse,), iters=(6,), max_dist=(max_dist,),
                              min_inliers=0.0, **normals)
        screened.append((r.inliers if torch.isfinite(r.relative).all() else -1.0, i, r.relative))
    return [rel.double() for _, _, rel in sorted(screened, key=lambda c: (-c[0], c[1]))[:keep]]


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
