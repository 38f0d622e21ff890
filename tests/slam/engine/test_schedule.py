"""Which frames are mapped (slam/engine/schedule.py): ESLAM's fixed schedule, and mapping by need."""

from types import SimpleNamespace

from slam.engine.schedule import call_iters, is_keyframe, mapping_reason
from slam.engine.state import RunState


def _state(losses, last_mapped, initialized=True):
    st = RunState(initialized=initialized, last_mapped=last_mapped)
    st.tracking = [{"frame": i, "loss": v, "iters": 1, "inliers": 1.0, "trusted": True} for i, v in enumerate(losses)]
    return st


def test_every_frame_maps_the_fixed_schedule_the_first_and_the_last():
    m = SimpleNamespace(schedule="every_frame", every_frame=4)
    reasons = [(k, mapping_reason(k, _state([1.0] * (k + 1), 0), m, 12)) for k in range(12)]
    assert [(k, r) for k, r in reasons if r] == [(0, "schedule"), (4, "schedule"), (8, "schedule"), (11, "last")]
    assert mapping_reason(5, _state([1.0] * 6, -1, initialized=False), m, 12) == "first"


def test_by_need_maps_while_young_after_a_gap_and_when_the_map_explains_a_frame_worse():
    m = SimpleNamespace(schedule="by_need", every_frame=1, need_young=5, need_max_gap=3, need_loss_factor=1.2)
    steady = [1.0] * 10
    assert mapping_reason(4, _state(steady[:5], 3), m, 100) == "young"
    assert mapping_reason(10, _state(steady + [1.1], 9), m, 100) is None  # 1.1 < 1.2 x median
    assert mapping_reason(10, _state(steady + [1.3], 9), m, 100) == "loss"  # the map explains it worse: new space
    assert mapping_reason(10, _state(steady + [1.0], 7), m, 100) == "gap"  # three frames since the last mapped one
    assert mapping_reason(99, _state(steady + [1.0], 98), m, 100) == "last"


def test_a_routine_refresh_takes_need_gap_iters_and_every_other_call_mapping_iters():
    m = SimpleNamespace(schedule="by_need", every_frame=1, need_young=5, need_max_gap=3, need_loss_factor=1.2,
                        need_gap_iters=2)
    steady = [1.0] * 10
    assert call_iters(4, _state(steady[:5], 3), m, 100) == 0  # young
    assert call_iters(10, _state(steady + [1.0], 7), m, 100) == 2  # only the gap: a routine refresh
    assert call_iters(10, _state(steady + [1.3], 7), m, 100) == 0  # the gap and new space: a full call
    assert call_iters(10, _state(steady + [1.3], 9), m, 100) == 0
    assert call_iters(99, _state(steady + [1.0], 96), m, 100) == 0  # the last frame
    assert call_iters(10, _state(steady + [1.1], 9), m, 100) is None
    assert call_iters(3, _state([], -1, initialized=False), m, 100) == 0  # the first frame with depth


def test_the_loop_gives_each_call_its_iterations(tiny_seq):
    """End to end, inline: the carried Adam moments count the steps the calls took (the warm-up has its own)."""
    from slam.config import load_config
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from tests.slam.conftest import TINY

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=false", "mapping.schedule=by_need",
                                    "mapping.need_young=2", "mapping.need_max_gap=2", "mapping.need_loss_factor=1000",
                                    "mapping.need_gap_iters=1", "mapping.optimizer_state=persistent"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    try:
        for k in range(6):
            s.step(k)
        # frame 0 the warm-up, 1 young (3 iterations), 3 a routine refresh (1), 5 the last frame (3)
        assert {float(v["step"]) for v in s.mapper.moments.state.values()} == {7.0}
    finally:
        s.close()


def test_by_need_makes_a_keyframe_every_keyframe_every_frames_whatever_positions_its_calls_fall_on(tiny_seq,
                                                                                                   monkeypatch):
    """By need, one call off the multiples of ``keyframe_every`` (a loss-triggered one) shifts every later refresh
    off them too: 20b7b9c, which kept ESLAM's rule (position % keyframe_every == 0), then added no keyframe again
    (here: frame 0 only, of 16)."""
    import slam.engine.system as system_mod
    from slam.config import load_config
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from tests.slam.conftest import TINY

    m = SimpleNamespace(schedule="by_need", keyframe_every=4)
    assert is_keyframe(9, RunState(last_keyframe=-1), m, first=True)
    assert [k for k in range(3, 16) if is_keyframe(k, RunState(last_keyframe=3), m, False)] == list(range(7, 16))
    every = SimpleNamespace(schedule="every_frame", keyframe_every=4)  # ESLAM's rule where the calls are fixed
    assert [k for k in range(1, 13) if is_keyframe(k, RunState(last_keyframe=0), every, False)] == [4, 8, 12]

    mapped = {0, 3, 7, 11, 15}  # a loss-triggered call at 3, then a routine refresh every fourth frame
    monkeypatch.setattr(system_mod, "call_iters", lambda k, st, mapping, n: 0 if k in mapped else None)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=16", "parallel=false",
                                    "mapping.schedule=by_need", "mapping.keyframe_every=4"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    try:
        s.run(progress=False)
        assert [kf.index for kf in s.keyframes.frames] == [0, 7, 11, 15]
        assert s.state.last_keyframe == 15
    finally:
        s.close()
