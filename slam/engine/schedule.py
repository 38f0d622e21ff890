"""Which frames are mapped: ESLAM's fixed schedule, or mapping by need (ours; ``mapping.schedule: by_need``).

``every_frame`` maps every ``mapping.every_frame``-th frame. ``by_need`` maps a frame (one the tracker trusts, with
depth) when the map is young (the first ``need_young`` frames), when ``need_max_gap`` frames have passed since the
last mapped one, or when the map explains the frame worse than it explained the recent ones: its tracking loss is
above ``need_loss_factor`` times the median of the last :data:`HISTORY` tracked frames' (new space in view, or a
map that has fallen behind the camera). The first frame with depth and the last frame are always mapped. Every
input is fixed by the frame numbers and the schedule, never by timing, so both loop modes stay deterministic.
"""

from __future__ import annotations

import statistics

from slam.engine.state import RunState

HISTORY = 10


def mapping_due(k: int, st: RunState, mapping, n_frames: int) -> bool:
    """Whether trusted frame position ``k`` (with depth) is mapped; ``mapping``: the ``mapping`` config, ``st``: the
    run state after frame ``k`` was tracked and recorded."""
    if not st.initialized or k == n_frames - 1:
        return True
    if mapping.schedule == "every_frame":
        return k % mapping.every_frame == 0
    if k < mapping.need_young or k - st.last_mapped >= mapping.need_max_gap:
        return True
    losses = [t["loss"] for t in st.tracking[-HISTORY - 1:-1] if t["trusted"]]
    return len(losses) >= 3 and st.tracking[-1]["loss"] > mapping.need_loss_factor * statistics.median(losses)
