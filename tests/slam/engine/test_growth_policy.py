"""A map that grows: when a frame's depth nears the box it grows there by whole coarse cells, up to a cap (with an
event); in both loop modes the tracker reads exactly the maps the schedule names, grown, and a run repeats."""

import hashlib

import pytest
import torch

import slam.engine.map_worker as mw
import slam.engine.mapper as mapper_mod
import slam.engine.tracking as tracking_mod
from slam.config import load_config
from slam.core.pose import matrix_to_pose
from slam.data.types import Intrinsics
from slam.engine.growth_policy import SceneGrowth
from slam.model.box_resize import pad_state
from tests.slam.conftest import GROWING, TINY


def _decide(extra=(), depth=2.0, box=((-3.0, 3.0), (-3.0, 3.0), (-1.0, 2.1)), radius=None):
    """What SceneGrowth decides for a flat wall ``depth`` metres ahead of a camera at the origin looking along +z
    (points x in +-1.6, y in +-1.2, z = depth), and the events it logged."""
    events = []
    g = SceneGrowth(load_config("synthetic", list(extra), profile="quality"),
                    lambda k, what, **kw: events.append((k, what, kw)), radius=radius)
    intr = Intrinsics(fx=50.0, fy=50.0, cx=39.5, cy=29.5, height=60, width=80)
    step = g.decide(3, torch.full((60, 80), depth), matrix_to_pose(torch.eye(4)), intr, torch.tensor(box))
    return g, step, events


def test_growth_triggers_where_the_depth_nears_the_box():
    _, step, _ = _decide(["scene.grow=true"])
    assert step.cells == {"z+": 1} and step.upper == (0.0, 0.0, 0.24) and step.lower == (0.0, 0.0, 0.0)
    _, step, _ = _decide(["scene.grow=true"], depth=2.5)  # 2.5 + 0.3 - 2.1 = 0.7 m: three cells
    assert step.cells == {"z+": 3}
    assert _decide(["scene.grow=true"], depth=1.7)[1] is None  # 1.7 + 0.3 m is inside
    assert _decide()[1] is None  # grow: auto keeps a given box (the synthetic preset's)
    assert _decide(["scene.grow=false", "bound=auto"])[1] is None
    assert SceneGrowth(load_config("synthetic", ["bound=auto"], profile="quality"), None).enabled


def test_with_grow_reach_box_only_depth_within_the_automatic_boxs_radius_grows_it():
    """The wall is 2.0-2.9 m from the camera (2 m ahead, up to 1.6 m aside): beyond a 1.9 m radius nothing counts,
    within 3 m all of it; grow_reach: depth (the default) counts it whatever the radius."""
    box = ["scene.grow=true", "scene.grow_reach=box"]
    assert _decide(box, radius=1.9)[1] is None
    assert _decide(box, radius=3.0)[1].cells == {"z+": 1}
    assert _decide(["scene.grow=true"], radius=1.9)[1].cells == {"z+": 1}
    assert _decide(box)[1].cells == {"z+": 1}  # a given box has no radius: every reading counts


def test_the_cap_stops_growth_with_one_event_per_side():
    g, step, events = _decide(["scene.grow=true", "scene.grow_max_extent=3.5"], depth=2.5)
    assert step.cells == {"z+": 1}  # 3.1 m + 0.24 fits in 3.5 m, a second cell would not
    assert len(events) == 1 and events[0][2] == {"growth_capped": "z+"} and "grow_max_extent" in events[0][1]
    assert g.state_dict() == {"capped": ["z+"]}
    g.decide(4, torch.full((60, 80), 2.5), matrix_to_pose(torch.eye(4)),
             Intrinsics(50.0, 50.0, 39.5, 29.5, 60, 80), torch.tensor([[-3.0, 3.0], [-3.0, 3.0], [-1.0, 2.34]]))
    assert len(events) == 1  # said once


def _digest(state: dict) -> str:
    h = hashlib.sha1()
    for name, t in state.items():
        h.update(name.encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _run(tiny_seq, monkeypatch, parallel: bool):
    """A 10-frame run whose box grows; what each tracking call read, and what each mapping call left, grown by
    every growth after it (the maps the schedule hands the tracker later)."""
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=10", *GROWING,
                                    f"parallel={str(parallel).lower()}"], profile="quality")
    seen, written, pending = {}, {}, []
    real_track, real_map, real_grow = tracking_mod.track_frame, mapper_mod.map_frame, mw.MapWorker.grow

    def track(scene, *a, **k):  # the map read, and the maps mapping calls left so far as they are now (grown)
        if len(s.state.est) not in seen:
            seen[len(s.state.est)] = _digest(scene.state_dict()), {m: _digest(st) for m, st in dict(written).items()}
        return real_track(scene, *a, **k)

    def mapping(scene, index, *a, **k):
        res = real_map(scene, index, *a, **k)
        written[index] = {n: t.detach().clone() for n, t in scene.state_dict().items()}
        return res

    def grow(worker, lower, upper):
        pending.append([p["k"] for p in worker.state_dict()["pending"]])
        pads = real_grow(worker, lower, upper)
        for m in written:
            written[m] = pad_state(written[m], pads)
        return pads

    monkeypatch.setattr(tracking_mod, "track_frame", track)
    monkeypatch.setattr(mapper_mod, "map_frame", mapping)
    monkeypatch.setattr(mw.MapWorker, "grow", grow)
    s = SLAM(cfg, load_data(cfg))
    s.run(progress=False)
    s.close()
    return s, seen, written, pending


@pytest.mark.parametrize("parallel", [True, False])
def test_with_growth_the_tracker_reads_the_maps_the_schedule_names_and_a_run_repeats(tiny_seq, monkeypatch,
                                                                                       parallel):
    s, seen, written, pending = _run(tiny_seq, monkeypatch, parallel)
    grown = [e for e in s.state.events if "growth" in e]
    assert grown and all(e["growth"]["sides"] == {"x-": 1} for e in grown), s.state.events
    assert s.aabb[0, 0] < -1.6 and torch.equal(s.scene.aabb.cpu(), s.aabb)
    at = grown[0]["frame"]
    assert s.state.sizes[at][0] == grown[0]["growth"]["parameters"] > s.state.sizes[at - 1][0]
    first = min(written)
    for j, (digest, left) in seen.items():
        m = max([k for k in left if k <= j - s.mapper.lag] or [first])
        assert digest == left[m], f"frame {j} tracked against another map than mapping call {m} left (grown)"
    assert _digest(s.scene.state_dict()) == _digest(written[max(written)]) == _digest(s.mapper.track_scene.state_dict())
    assert any(pending) == parallel, f"calls pending at the growths: {pending}"
    again, _, _, _ = _run(tiny_seq, monkeypatch, parallel)
    assert torch.equal(torch.stack(s.state.est), torch.stack(again.state.est))
    assert again.state.events == s.state.events and _digest(again.scene.state_dict()) == _digest(s.scene.state_dict())


def test_the_run_gives_its_growth_the_automatic_boxs_starting_half_size(tiny_seq):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    for bound, expect in (("auto", lambda s: (s.bound[0][1] - s.bound[0][0]) / 2), (None, lambda s: None)):
        over = [f"data.path={tiny_seq}", "data.max_frames=2", "parallel=false", "scene.grow=true",
                "scene.grow_reach=box", *([f"bound={bound}"] if bound else [])]
        cfg = load_config("synthetic", over, profile="quality")
        s = SLAM(cfg, load_data(cfg))
        try:
            assert s.growth.radius == expect(s) and (s.growth.radius is None) == (bound is None)
            if bound:
                assert 0.5 < s.growth.radius < 5.0
        finally:
            s.close()
