"""The motion model (slam/engine/tracking.py, ``predict``): a velocity is taken only between two trusted poses, so
a lost stretch holds the last pose instead of extrapolating a correction frame after frame (a fixed-box walk ran
out to 28 km that way). A frame without depth (``track_without_depth``) is turned by its colour when that lowers
the colour error and moves the camera plausibly, else it keeps the prediction."""

import torch

from slam.config import load_config
from slam.core.pose import pose_to_matrix, rotation_angle
from slam.core.pose import matrix_to_pose
from slam.engine.recovery import TrackInput
from slam.engine.state import RunState
from slam.engine.tracking import Timeline, predict, track_without_depth
from slam.engine.tracking_guard import TrackingGuard
from tests.slam.conftest import EditedDataset
from tests.slam.engine.test_recovery import FAST
from tests.slam.engine.test_tracker import ROOM_CFG, Room, room_image, turned


def _pose(x):
    return torch.tensor([1.0, 0.0, 0.0, 0.0, x, 0.0, 0.0])


def test_constant_velocity_only_between_two_trusted_poses():
    est = [_pose(0.0), _pose(0.1), _pose(0.2)]
    pred, what = predict(est, [True, True, True], "icp")
    assert what == "constant-velocity pose" and abs(float(pred[4]) - 0.3) < 1e-6
    for trusted in ([True, False, True], [True, True, False]):  # a jump back, or a lost last pose
        pred, what = predict(est, trusted, "icp")
        assert what == "previous pose" and torch.equal(pred, est[-1])
    assert predict(est, [True] * 3, "previous")[1] == "previous pose"
    assert predict(est[:1], [True], "const_speed")[1] == "previous pose"


def test_a_lost_stretch_after_a_jump_back_holds_the_pose(tiny_seq, monkeypatch):
    """Frames 8-10 are lost with results 40 cm off (a wild track), frame 11 comes back (tracked, recovered or
    relocalised near the truth) and frames 12-17 cannot be tracked at all (no rays in the box), so their poses are
    the prediction. Extrapolating frame 11's jump back, as before, put frame 12 2.5 m off (measured); held, every
    lost frame stays within the gap's own motion of the truth."""
    import slam.engine.tracking
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *FAST, "tracking.iters=4", "tracking.init=icp",
                                        "tracking.relocalize_after=0"], profile="quality")  # the lost stretch stays lost
    s = SLAM(cfg, EditedDataset(load_data(cfg)))
    depth_of = {k: s.frames.get(k).depth for k in range(18)}
    real_recover, real_track = slam.engine.tracking.recover, slam.engine.tracking.track_frame

    def frame_of(depth):
        return next(k for k, d in depth_of.items() if torch.equal(d, depth))

    def recover(inp, res, prev, dt, starts, prediction, event):
        if frame_of(inp.depth) in (8, 9, 10):
            res.pose = prediction.clone()
            res.pose[4] += 0.4
            return res, False, "tracking lost (made to fail by the test)"
        return real_recover(inp, res, prev, dt, starts, prediction, event)

    def track_frame(scene, color, depth, intr, init, cfg, gen):
        res = real_track(scene, color, depth, intr, init, cfg, gen)
        if frame_of(depth) >= 12:
            res.ok, res.message = False, "made to fail by the test"
        return res

    monkeypatch.setattr(slam.engine.tracking, "recover", recover)
    monkeypatch.setattr(slam.engine.tracking, "track_frame", track_frame)
    s.run(progress=False)
    assert [k for k, t in enumerate(s.state.trusted) if not t] == [8, 9, 10, *range(12, 18)]
    err = [100 * float((pose_to_matrix(s.state.est[k])[:3, 3] - s.gt[k][:3, 3]).norm()) for k in range(18)]
    assert err[11] < 10.0, err  # back near the truth (re-tracked from frame 7's pose: 7.5 cm measured)
    # held at frame 11's pose: off by the camera's own motion since then (1.6 cm a frame here), nothing more
    for k in range(12, 18):
        moved = 100 * float((s.gt[k][:3, 3] - s.gt[11][:3, 3]).norm())
        assert err[k] <= err[11] + moved + 0.01, (k, err[k], err[11], moved)
    held = [e for e in s.state.events if e["frame"] >= 12]
    assert held and all("previous pose used" in e["event"] for e in held), held
    s.close()


def test_a_frame_without_depth_is_turned_by_its_colour_only_when_that_is_plausible():
    color, intr = room_image()
    pred = matrix_to_pose(turned(1.5, -2.0))  # the truth is the identity: the camera at the origin facing +z

    def track(overrides=(), image=color, last=None):
        cfg = load_config("synthetic", [*ROOM_CFG, *overrides], profile="quality")
        st = RunState(est=[last if last is not None else matrix_to_pose(torch.eye(4))], trusted=[True])
        inp = TrackInput(Room(), image, torch.zeros(image.shape[:2]), intr, cfg, torch.Generator().manual_seed(0),
                         TrackingGuard(cfg.tracking))
        events = []
        run = Timeline(dt=lambda k, j: (k - j) / 30, keyframes=list, frame_of=int,
                       event=lambda k, what, **extra: events.append({"frame": k, "event": what, **extra}))
        pose, tracked = track_without_depth(1, inp, st, pred, "constant-velocity pose", run)
        assert len(events) == 1 and events[0]["event"].startswith("no valid depth: "), events
        return pose, tracked, events[0]

    pose, tracked, event = track()
    assert tracked and event["color_tracked"], event
    assert event["event"].startswith("no valid depth: tracked on colour from the constant-velocity pose"), event
    assert float(rotation_angle(pose_to_matrix(pose)[:3, :3])) < 0.01  # back to the truth (2.5 degrees off)
    for overrides, image, last, why in (
            (["tracking.without_depth=predict"], color, None, "not tracked, constant-velocity pose used"),
            ((), torch.full_like(color, 0.5), None, "the colour image has no contrast either"),
            # the last trusted pose is 1 m away: 30 m/s in one frame, whatever colour says
            ((), color, matrix_to_pose(torch.eye(4)) + torch.tensor([0, 0, 0, 0, 1.0, 0, 0]), "m/s")):
        pose, tracked, event = track(overrides, image, last)
        assert torch.equal(pose, pred) and why in event["event"] and not event["color_tracked"], event
