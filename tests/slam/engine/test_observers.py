"""The observer walk-through of docs/design.md ("Where a new thing goes"): one class, handed to the run."""

import dataclasses

import pytest

from slam.config import load_config
from tests.slam.conftest import TINY


def test_a_new_observer_sees_every_frame_through_a_read_only_view_and_can_stop_the_run(tiny_seq):
    from slam.engine.observers import Observer
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.engine.view import RunView

    class StopAtThree(Observer):  # the whole of a new observer
        def __init__(self):
            self.seen = []

        def on_frame(self, run, record):
            assert isinstance(run, RunView) and run.done == record.k + 1
            self.seen.append((record.frame, record.tracked, record.mapped, run.poses().shape))

        def stop_requested(self):
            return len(self.seen) >= 3

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    obs = StopAtThree()
    s.run(progress=False, observers=[obs])
    s.close()
    assert [f for f, *_ in obs.seen] == [0, 1, 2] and len(s.state.est) == 3  # stopped, as an interrupt would
    assert obs.seen[0][1:] == (False, True, (1, 4, 4)) and obs.seen[1][1] is True  # frame 0 maps, 1 is tracked
    view = s.view()
    with pytest.raises(dataclasses.FrozenInstanceError):
        view.scene = None  # a view cannot change the run it shows
    kfs = view.keyframes()
    assert kfs.positions == (0,) and kfs.poses.shape == (1, 4, 4) and kfs.depths[0].shape == (60, 80)
