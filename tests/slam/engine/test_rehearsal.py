"""The kernel preload (``preload_kernels``): it rehearses both calls before the first frame and leaves the run's
results as they were, bit for bit; a rehearsal that fails is a warning, not the run's end."""

import logging

import pytest
import torch

from slam.config import load_config
from tests.slam.conftest import TINY


def test_the_preload_rehearses_both_calls_and_changes_no_result(tiny_seq, monkeypatch):
    import slam.engine.rehearsal as rehearsal
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    calls = {"map": 0, "track": 0}

    def counted(name, fn):
        def wrapped(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return wrapped

    monkeypatch.setattr(rehearsal, "map_frame", counted("map", rehearsal.map_frame))
    monkeypatch.setattr(rehearsal, "track_frame", counted("track", rehearsal.track_frame))
    runs = {}
    for preload in (True, False):
        cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=true",
                                        "mapping.optimizer_state=persistent", f"preload_kernels={preload}"], profile="quality")
        s = SLAM(cfg, load_data(cfg))
        try:
            assert calls == {"map": 2, "track": 1}  # before the first frame (the second system: none more)
            s.run(progress=False)
            runs[preload] = (torch.stack(s.state.est), {k: v.clone() for k, v in s.scene.state_dict().items()})
        finally:
            s.close()
    assert torch.equal(runs[True][0], runs[False][0])
    for name, t in runs[True][1].items():
        assert torch.equal(t, runs[False][1][name]), name


def test_a_rehearsal_that_fails_is_a_warning(tiny_seq, caplog, monkeypatch):
    import slam.engine.rehearsal as rehearsal
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    def broken(*args, **kwargs):
        raise RuntimeError("kernel cache unreadable")

    monkeypatch.setattr(rehearsal, "map_frame", broken)
    monkeypatch.setattr(rehearsal, "track_frame", broken)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=true"], profile="quality")
    with caplog.at_level(logging.WARNING, logger="slam.engine.rehearsal"):
        s = SLAM(cfg, load_data(cfg))  # the preload fails, the system is made all the same
    try:
        assert [r.message for r in caplog.records] == [
            "kernel preload: the rehearsed tracking call failed (RuntimeError: kernel cache unreadable)",
            "kernel preload: the rehearsed mapping call failed (RuntimeError: kernel cache unreadable)"]
        monkeypatch.undo()
        s.run(progress=False)
        assert len(s.state.est) == 6 and all(s.state.trusted)
    finally:
        s.close()


@pytest.mark.parametrize("value", ["maybe", "2"])
def test_preload_kernels_is_a_checked_bool(value):
    from slam.errors import SlamInputError

    with pytest.raises(SlamInputError, match="preload_kernels"):
        load_config("synthetic", [f"preload_kernels={value}"], profile="quality")
