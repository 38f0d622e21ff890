"""Tracking that knows when it is lost: plausibility checks on each tracking result.

A result is implausible when its loss is far above the recent frames' (``lost_loss_factor`` times their median),
when the outlier rule keeps too few rays (``lost_min_inliers``), or when the pose jumps further than a camera
moves in the time between the frames (``max_speed`` metres per second, ``max_angular_speed`` degrees per
second). The loop then tries to recover (:mod:`slam.engine.recovery`: longer tracking from several starts, the best
chosen on common pixels) and, if that fails too, keeps the frame out of the map: a pose the tracker does not trust
never drags the map with it. After ``relocalize_after`` untrusted frames in a row it relocalises against the
keyframes and, on success, restarts the history from the recovered frame (:meth:`TrackingGuard.reset`), so a
camera that turned into space the map did not cover is let back in.
"""

from __future__ import annotations

import math
import statistics
from collections import deque

import torch

from slam.core.pose import pose_gap, pose_to_matrix

HISTORY = 10  # accepted frames whose loss makes "recent"


def motion(prev: torch.Tensor, new: torch.Tensor) -> tuple[float, float]:
    """Translation (metres) and rotation (degrees) between two ``[7]`` camera-to-world poses."""
    return pose_gap(pose_to_matrix(prev.detach().double()), pose_to_matrix(new.detach().double()))


class TrackingGuard:
    """Plausibility of tracking results, against the recent accepted ones.

    Args:
        cfg: the ``tracking`` config (``lost_loss_factor``, ``lost_min_inliers``, ``max_speed``,
            ``max_angular_speed``; 0 turns a check off).
    """

    def __init__(self, cfg):
        self.cfg = cfg
        self.losses: deque[float] = deque(maxlen=HISTORY)

    def reasons(self, loss: float, inliers: float, prev: torch.Tensor | None, new: torch.Tensor,
                dt_s: float, use_history: bool = True) -> list[str]:
        """Why a result looks wrong (empty: plausible). ``prev`` / ``new``: ``[7]`` poses; ``dt_s``: seconds
        between the two frames; ``use_history=False`` skips the loss-ratio check (relocalisation: the history
        is from before the gap)."""
        c = self.cfg
        out = []
        if not math.isfinite(loss):
            return ["no finite loss"]
        if use_history and c.lost_loss_factor > 0 and len(self.losses) >= 3:
            ref = statistics.median(self.losses)
            if loss > c.lost_loss_factor * ref:
                out.append(f"loss {loss:.3g} is {loss / ref:.1f}x the recent median {ref:.3g}")
        if c.lost_min_inliers > 0 and inliers < c.lost_min_inliers:
            out.append(f"only {100 * inliers:.0f} % of the rays are inliers")
        if prev is not None and dt_s > 0:
            dist, angle = motion(prev, new)
            if c.max_speed > 0 and dist > c.max_speed * dt_s:
                out.append(f"moved {100 * dist:.1f} cm in {1000 * dt_s:.0f} ms (> {c.max_speed:g} m/s)")
            if c.max_angular_speed > 0 and angle > c.max_angular_speed * dt_s:
                out.append(f"turned {angle:.1f} deg in {1000 * dt_s:.0f} ms (> {c.max_angular_speed:g} deg/s)")
        return out

    def accept(self, loss: float) -> None:
        """Record the loss of a result the loop trusts."""
        if math.isfinite(loss):
            self.losses.append(float(loss))

    def reset(self, loss: float) -> None:
        """Start the history again from one trusted result (after relocalisation: the frames before the gap no
        longer say what a good loss is here)."""
        self.losses.clear()
        self.accept(loss)

    def state_dict(self) -> dict:
        """``{"losses": [...]}``: the history of accepted losses."""
        return {"losses": list(self.losses)}

    def load_state_dict(self, state: dict | list) -> None:
        """Restore a :meth:`state_dict` (or the bare list of losses that run checkpoints before it stored)."""
        losses = state["losses"] if isinstance(state, dict) else state
        self.losses = deque((float(v) for v in losses), maxlen=HISTORY)
