"""Tracking that knows when it is lost: implausible results are events, get a recovery attempt, and a pose the
tracker does not trust is never mapped."""

import math

import pytest
import torch

import slam.engine.tracking as tracking_mod
from slam.config import load_config
from slam.engine.tracking_guard import TrackingGuard, motion
from tests.slam.conftest import TINY

I7 = torch.tensor([1.0, 0, 0, 0, 0, 0, 0])


def _at(x=0.0, yaw_deg=0.0):
    h = math.radians(yaw_deg) / 2
    return torch.tensor([math.cos(h), 0, 0, math.sin(h), x, 0, 0])


def test_motion_in_metres_and_degrees():
    d, a = motion(I7, _at(0.3, 10.0))
    assert d == pytest.approx(0.3) and a == pytest.approx(10.0, abs=1e-5)


def test_each_check_names_its_reason():
    cfg = load_config("synthetic", profile="quality").tracking
    g = TrackingGuard(cfg)
    for v in (0.1, 0.12, 0.11):
        g.accept(v)
    dt = 1 / 30
    assert g.reasons(0.12, 0.95, I7, _at(0.01, 1.0), dt) == []
    assert "x the recent median" in g.reasons(0.9, 0.95, I7, I7, dt)[0]
    assert "inliers" in g.reasons(0.1, 0.3, I7, I7, dt)[0]
    assert "m/s" in g.reasons(0.1, 0.95, I7, _at(0.2), dt)[0]  # 20 cm in 33 ms = 6 m/s
    assert "deg/s" in g.reasons(0.1, 0.95, I7, _at(0.0, 30.0), dt)[0]  # 900 deg/s
    off = load_config("synthetic", ["tracking.lost_loss_factor=0", "tracking.max_speed=0"], profile="quality").tracking
    assert TrackingGuard(off).reasons(100.0, 0.95, I7, _at(5.0), dt) == []


def _system(tiny_seq, extra=()):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    # a map trained enough for tracking to pull a wrong start back (TINY's 5 warm-up iterations are not)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=8", "mapping.every_frame=1",
                                    "mapping.iters_first=60", "mapping.iters=5", "tracking.iters=8", *extra], profile="quality")
    return SLAM(cfg, load_data(cfg))


def _jump_first_attempt(monkeypatch, frame, always=False):
    """track_frame returns a pose 40 cm off (a jump no camera makes in 1/30 s) for frame ``frame``."""
    real = tracking_mod.track_frame
    calls = {"n": 0}

    def track(scene, color, depth, intr, init, cfg, gen, **kw):
        res = real(scene, color, depth, intr, init, cfg, gen, **kw)
        if track.k == frame and (always or calls["n"] == 0):
            calls["n"] += 1
            res.pose = res.pose.clone()
            res.pose[4] += 0.4
        return res

    track.k = -1
    import slam.engine.recovery

    monkeypatch.setattr(tracking_mod, "track_frame", track)  # the first attempt
    monkeypatch.setattr(slam.engine.recovery, "track_frame", track)  # the recovery attempts
    return track


def test_an_implausible_jump_is_recovered(tiny_seq, monkeypatch):
    s = _system(tiny_seq)
    track = _jump_first_attempt(monkeypatch, 5)
    for k in range(8):
        track.k = k
        s.step(k)
    ev = [e for e in s.state.events if e["frame"] == 5]
    assert len(ev) == 1 and ev[0].get("recovered") and "m/s" in ev[0]["event"]
    d, _ = motion(s.state.est[4], s.state.est[5])
    assert d < 0.1 and s.state.trusted[5]
    s.close()


def test_a_frame_that_stays_implausible_is_not_mapped(tiny_seq, monkeypatch):
    s = _system(tiny_seq)
    track = _jump_first_attempt(monkeypatch, 5, always=True)
    mapped = []
    real_submit = s.mapper.submit
    s.mapper.submit = lambda job: (mapped.append(job.k), real_submit(job))
    for k in range(8):
        track.k = k
        s.step(k)
    ev = [e for e in s.state.events if e["frame"] == 5]
    assert len(ev) == 1 and ev[0].get("lost") and "recovery attempts failed" in ev[0]["event"]
    assert not s.state.trusted[5] and 5 not in mapped and {4, 6, 7} <= set(mapped)
    d, _ = motion(s.state.est[4], s.state.est[5])
    assert d < 0.1  # the prediction, not the jump
    assert 5 not in [kf.index for kf in s.keyframes.frames]
    s.close()
