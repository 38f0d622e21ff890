"""Which frames are mapped: ESLAM's fixed schedule, or mapping by need (ours; ``mapping.schedule: by_need``).

``every_frame`` maps every ``mapping.every_frame``-th frame. ``by_need`` maps a frame (one the tracker trusts, with
depth) when the map is young (the first ``need_young`` frames), when ``need_max_gap`` frames have passed since the
last mapped one, or when the map explains the frame worse than it explained the recent ones: its tracking loss is
above ``need_loss_factor`` times the median of the last :data:`HISTORY` tracked frames' (new space in view, or a
map that has fallen behind the camera). The first frame with depth and the last frame are always mapped. A call
made only because of the gap (a routine refresh) takes ``need_gap_iters`` iterations where that is set. Every
input is fixed by the frame numbers and the schedule, never by timing, so both loop modes stay deterministic.

A mapped frame becomes a keyframe (:func:`is_keyframe`) by ESLAM's rule under ``every_frame`` (its position a multiple
of ``keyframe_every``), and under ``by_need`` once ``keyframe_every`` frames have passed since the last keyframe: the
calls of that schedule fall on no fixed multiple, and one loss-triggered call would shift every later refresh off
the multiples for good.
"""

from __future__ import annotations

import statistics

from slam.engine.state import RunState

HISTORY = 10


def mapping_reason(k: int, st: RunState, mapping, n_frames: int) -> str | None:
    """Why trusted frame position ``k`` (with depth) is mapped, or None when it is not: ``"first"`` (the first frame
    with depth), ``"last"``, ``"schedule"`` (``every_frame``), ``"young"``, ``"loss"`` (its tracking loss is above
    ``need_loss_factor`` x the recent median) or ``"gap"`` (``need_max_gap`` frames since the last mapped one).
    ``mapping``: the ``mapping`` config; ``st``: the run state after frame ``k`` was tracked and recorded."""
    if not st.initialized:
        return "first"
    if k == n_frames - 1:
        return "last"
    if mapping.schedule == "every_frame":
        return "schedule" if k % mapping.every_frame == 0 else None
    if k < mapping.need_young:
        return "young"
    losses = [t["loss"] for t in st.tracking[-HISTORY - 1:-1] if t["trusted"]]
    if len(losses) >= 3 and st.tracking[-1]["loss"] > mapping.need_loss_factor * statistics.median(losses):
        return "loss"
    return "gap" if k - st.last_mapped >= mapping.need_max_gap else None


def call_iters(k: int, st: RunState, mapping, n_frames: int) -> int | None:
    """None when trusted frame position ``k`` (with depth) is not mapped, else its call's iterations: 0 (the call
    takes ``mapping.iters``), or ``need_gap_iters`` for a call made only because ``need_max_gap`` frames passed."""
    reason = mapping_reason(k, st, mapping, n_frames)
    if reason is None:
        return None
    return mapping.need_gap_iters if reason == "gap" else 0


def is_keyframe(k: int, st: RunState, mapping, first: bool) -> bool:
    """Whether the mapping call of frame position ``k`` (``first``: the warm-up) adds it to the keyframes: see the
    module's text. ``st``: the run state before the call is recorded (``last_keyframe``)."""
    if first:
        return True
    if mapping.schedule == "every_frame":
        return k % mapping.keyframe_every == 0
    return k - st.last_keyframe >= mapping.keyframe_every
