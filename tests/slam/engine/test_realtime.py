"""Real-time replay (slam/engine/realtime.py, ``data.realtime``): frames arrive at their recorded rate, the loop
takes the newest one that has arrived and passes over the ones it missed; the trajectory holds the processed
frames, ``metrics.json`` counts both and the latency from arrival to pose. Timed here by a simulated clock, so the
frames taken are exact."""

import json

import numpy as np
import pytest
import torch

from slam.config import load_config
from slam.core.pose import pose_to_matrix
from slam.engine.realtime import Replay, arrival_times, latency_summary
from tests.slam.conftest import TINY


class Clock:
    """Simulated seconds: ``sleep`` moves time on, and so does each processed frame (``cost`` seconds)."""

    def __init__(self, cost: float):
        self.t, self.cost, self.slept = 0.0, cost, []

    def now(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s


def test_the_newest_frame_that_has_arrived_is_taken_and_a_fast_loop_waits():
    times = arrival_times([0, 1, 2, 3, 4, 5, 6], None)  # no timestamps: 30 Hz per dataset frame
    assert np.allclose(times, np.arange(7) / 30)
    assert np.allclose(arrival_times([2, 4], [10.0, 10.5, 11.0, 11.2, 11.25]), [0.0, 0.25])
    clock = Clock(0.0)
    r = Replay(times, clock.now, clock.sleep)
    assert r.take(0) == 0 and clock.slept == []  # the first frame arrives when the clock starts
    clock.t = 0.105  # a frame took 105 ms: frames 1-3 arrived meanwhile, 3 is the newest
    assert r.take(1) == 3
    assert r.take(4) == 4 and clock.slept == [pytest.approx(4 / 30 - 0.105)]  # faster than the camera: it waits
    r.start(5)  # a resumed run: the clock restarts with frame 5 arriving now
    assert r.arrival(5) == clock.t and r.take(5) == 5
    assert latency_summary([0.1, 0.2, 0.3], 4) == {"frames_processed": 3, "frames_dropped": 4,
                                                   "latency_median_s": 0.2, "latency_p95_s": 0.29,
                                                   "latency_max_s": 0.3}


def _simulated(monkeypatch, cost: float) -> Clock:
    """Make the loop's replay run on a simulated clock where each frame costs ``cost`` seconds."""
    import slam.engine.system as system_mod

    clock = Clock(cost)
    monkeypatch.setattr(system_mod, "Replay", lambda times: Replay(times, clock.now, clock.sleep))
    real_step = system_mod.SLAM.step

    def step(self, k):
        rec = real_step(self, k)
        clock.t += clock.cost
        return rec

    monkeypatch.setattr(system_mod.SLAM, "step", step)
    return clock


@pytest.mark.parametrize("parallel", ["true", "false"])
def test_a_slow_loop_drops_the_frames_it_missed_and_reports_them(tiny_seq, tmp_path, monkeypatch, parallel):
    """105 ms a frame against a 30 Hz camera: frames 0, 3, 6, 9 and the last (11) are processed, the other seven
    dropped, each processed frame's pose 105 ms after it was taken (later than its arrival by the wait)."""
    from slam.run.runner import run_to_folder

    _simulated(monkeypatch, 0.105)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=12", f"parallel={parallel}",
                                    "data.realtime=true", "mapping.every_frame=2"], profile="quality")
    m = run_to_folder(cfg, tmp_path / "rt", progress=False, mesh=False)
    rows = [ln.split()[0] for ln in (tmp_path / "rt" / "trajectory.txt").read_text().splitlines()
            if not ln.startswith("#")]
    gt_rows = [ln.split()[0] for ln in (tmp_path / "rt" / "trajectory_gt.txt").read_text().splitlines()
               if not ln.startswith("#")]
    assert m["num_frames"] == 5 and len(rows) == 5 and rows == gt_rows
    csv = (tmp_path / "rt" / "frames.csv").read_text().splitlines()
    assert [int(r.split(",")[1]) for r in csv[1:]] == [0, 3, 6, 9, 11]
    rt = m["realtime"]
    assert rt["frames_processed"] == 5 and rt["frames_dropped"] == 7
    # from arrival to pose: frame 0 0.105 s, 3 (arrived 0.100, posed 0.210) 0.110, 6 0.115, 9 0.120, and 11
    # (arrived 0.367, posed 0.525) 0.158
    assert rt["latency_max_s"] == pytest.approx(0.525 - 11 / 30, abs=1e-4)
    assert rt["latency_median_s"] == pytest.approx(0.115, abs=1e-4)
    assert m["ate_rmse_m"] is not None and m["ate_rmse_m"] < 0.05
    saved = json.loads((tmp_path / "rt" / "metrics.json").read_text())
    assert saved["realtime"] == rt


def test_a_stopped_real_time_run_resumes_from_the_frames_it_processed(tiny_seq, tmp_path, monkeypatch):
    """The frames passed over before a stop stay passed over; the clock restarts at the resumed frame."""
    from slam.run.checkpoint import load_run
    from slam.run.runner import RunInterrupted, run_to_folder

    clock = _simulated(monkeypatch, 0.105)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=12", "parallel=true",
                                    "data.realtime=true"], profile="quality")
    out = tmp_path / "rt"
    with pytest.raises(RunInterrupted):
        run_to_folder(cfg, out, progress=False, mesh=False, stop_after=2)
    state = load_run(out / "checkpoint.pt")["extra"]["run"]["state"]
    assert state["dropped"] == [1, 2] and len(state["latency"]) == 2
    clock.t += 100.0  # a resume hours later: nothing arrived while the run was stopped
    m = run_to_folder(cfg, out, progress=False, mesh=False, resume=True)
    csv = (out / "frames.csv").read_text().splitlines()
    # resumed at frame 4, which arrives as the clock restarts: 4, then 7, 10 and the last
    assert [int(r.split(",")[1]) for r in csv[1:]] == [0, 3, 4, 7, 10, 11]
    assert m["realtime"]["frames_dropped"] == 6 and m["realtime"]["frames_processed"] == 6
    assert torch.isfinite(torch.tensor(m["ate_rmse_m"]))


def test_a_real_time_run_tracks_on_while_the_mapper_is_busy(tiny_seq, monkeypatch):
    """``mapping.realtime_sync: free``: a mapping call held up (here until frame 5 is tracked) does not hold up the
    tracker, which tracks frames 2-5 on the map the warm-up left, and the frames that want mapping meanwhile are
    declined, not queued; every frame is tracked on a map a finished call left, never on one mid-call."""
    import threading

    import slam.engine.mapper as mapper_mod
    import slam.engine.map_worker as worker_mod
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from tests.slam.engine.test_map_worker import _digest

    _simulated(monkeypatch, 0.0)  # faster than the camera: every frame is taken
    gate, written, seen, mapped = threading.Event(), {}, {}, []
    real_map, real_sync = mapper_mod.map_frame, worker_mod.MapWorker.sync

    def mapping(scene, index, *a, **k):
        mapped.append(index)
        if index == 1:
            assert gate.wait(60), "the tracker never reached frame 5: it waited for the mapper"
        res = real_map(scene, index, *a, **k)
        written[index] = _digest(scene)
        return res

    def sync(self, j, idle=None):
        out = real_sync(self, j, idle)
        seen[j] = _digest(self.track_scene)
        if j == 6:
            gate.set()  # frame 5 is tracked
        return out

    monkeypatch.setattr(mapper_mod, "map_frame", mapping)
    monkeypatch.setattr(worker_mod.MapWorker, "sync", sync)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=10", "parallel=true",
                                    "mapper_process=false", "data.realtime=true", "mapping.every_frame=1",
                                    "mapping.realtime_warmup=wait"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    try:
        s.run(progress=False)
    finally:
        s.close()
        gate.set()
    assert len(s.state.est) == 10 and not s.state.dropped
    assert mapped[:2] == [0, 1] and not set(mapped) & {2, 3, 4, 5}
    assert s.mapper.declined >= 4 and s.mapper.calls == len(mapped)
    assert all(seen[j] == written[0] for j in range(1, 6))
    for j, digest in seen.items():  # frame 0 starts the map: not tracked
        assert j == 0 or digest in {written[k] for k in mapped if k < j}, f"frame {j} tracked on a map no finished call left"
    assert _digest(s.scene) == written[mapped[-1]] == _digest(s.mapper.track_scene)


def _run_holding_calls(tiny_seq, monkeypatch, frames: int, no_depth: tuple, release: dict):
    """A real-time run (a mapping thread, a simulated clock faster than the camera) of the tiny room's first
    ``frames`` frames, those in ``no_depth`` without depth, in which the mapping call of frame ``release[k]`` is
    held until frame ``k`` is posed, and frame ``k + 1`` is taken only once that call has finished, so which frames
    arrive while a call runs is fixed. Returns the (closed) system and the frames mapped, in order."""
    import threading
    import time

    import slam.engine.mapper as mapper_mod
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from tests.slam.conftest import EditedDataset

    _simulated(monkeypatch, 0.0)
    gates, mapped = {c: threading.Event() for c in release.values()}, []
    real_map = mapper_mod.map_frame

    def mapping(scene, index, *a, **k):
        mapped.append(index)
        if index in gates:
            assert gates[index].wait(60), f"the tracker never got past the call of frame {index}: it waited for it"
        return real_map(scene, index, *a, **k)

    monkeypatch.setattr(mapper_mod, "map_frame", mapping)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], f"data.max_frames={frames}", "parallel=true",
                                    "mapper_process=false", "data.realtime=true", "mapping.every_frame=1"],
                      profile="quality")
    s = SLAM(cfg, EditedDataset(load_data(cfg), no_depth=no_depth))
    real_step = s.step

    def step(k):
        rec = real_step(k)
        if k in release:
            gates[release[k]].set()
            while not s.mapper.idle():
                time.sleep(0.01)
        return rec

    s.step = step
    try:
        s.run(progress=False)
    finally:
        s.close()
        for g in gates.values():
            g.set()
    return s, mapped


@pytest.mark.parametrize("no_depth", [(), (3,)])
def test_the_frames_before_the_map_reaches_the_camera_are_tracked_by_depth_odometry(tiny_seq, tmp_path, monkeypatch,
                                                                                   no_depth):
    """``mapping.realtime_warmup: odometry``: while the warm-up call runs (held here until frame 5 is posed) the
    frames that arrive are taken, not waited over: each is registered by depth ICP to the frame before it, chained
    from frame 0, without the map and not mapped. The first such frame once the warm-up has finished (6) is mapped,
    the bridge, and odometry goes on until that call has finished too (held until frame 8 is posed); the tracker then
    takes over on a map that has seen where the camera is. A frame without depth among them keeps the prediction,
    untrusted, and the chain goes on from the frame before it."""
    from slam.run.outputs import write_frames

    s, mapped = _run_holding_calls(tiny_seq, monkeypatch, 10, no_depth, {5: 0, 8: 6})
    assert len(s.state.est) == 10 and not s.state.dropped
    odo = {e["frame"]: e for e in s.state.events if "odometry" in e}
    assert set(odo) == set(range(1, 9))
    assert all(odo[j]["odometry"] == (j not in no_depth) for j in odo)
    assert all(s.state.trusted[j] == (j not in no_depth) for j in range(10))
    assert mapped[:2] == [0, 6] and {e["frame"] for e in s.state.tracking} == {9}
    ready = [e["frame"] for e in s.state.events if e["event"].startswith("first map ready")]
    assert ready == [9]  # the hand-over is said once, on the first frame tracked on the map
    assert [kf.index for kf in s.keyframes.frames][:2] == [0, 6]
    for j in range(1, 9):  # the tiny room's depth is exact: ICP registers each step to a few millimetres
        if j not in no_depth and j != 6:  # 6's pose is the bridge call's bundle-adjusted one
            rel_est = torch.linalg.solve(pose_to_matrix(s.state.est[0]), pose_to_matrix(s.state.est[j]))
            rel_gt = torch.linalg.solve(s.gt[0], s.gt[j])
            assert (rel_est[:3, 3] - rel_gt[:3, 3]).norm() < 0.003, j
    write_frames(s.view(), tmp_path)
    rows = [r.split(",") for r in (tmp_path / "frames.csv").read_text().splitlines()[1:]]
    assert [r[4] for r in rows[1:]] == ["prediction" if j in no_depth else "odometry" for j in range(1, 9)] + ["depth"]


def test_a_start_with_no_frame_to_bridge_with_hands_over_to_the_tracker(tiny_seq, monkeypatch):
    """The first frame after the warm-up has no depth, so it cannot be the bridge: odometry does not go on waiting
    for one (a camera whose depth stays out would never be tracked on the map), the tracker takes over on the first
    map from the next frame, and the frames after it are tracked and mapped as usual."""
    s, mapped = _run_holding_calls(tiny_seq, monkeypatch, 8, (4,), {3: 0})
    odo = {e["frame"]: e["odometry"] for e in s.state.events if "odometry" in e}
    assert odo == {1: True, 2: True, 3: True, 4: False}
    assert [e["frame"] for e in s.state.events if e["event"].startswith("first map ready")] == [4]
    assert {e["frame"] for e in s.state.tracking} == {5, 6, 7} and all(s.state.trusted[5:])
    assert mapped[0] == 0 and 4 not in mapped and 5 in mapped
    assert s.gt is not None and all(
        (pose_to_matrix(s.state.est[j])[:3, 3] - s.gt[j][:3, 3]).norm() < 0.02 for j in (5, 6, 7))


def test_a_real_time_run_with_the_mapping_process_maps_or_declines_every_frame(tiny_seq, tmp_path, monkeypatch):
    """The same in a child process (the realtime profile's): each frame the schedule maps is a call or declined,
    or was tracked by depth odometry before the map reached the camera (the first of those after the warm-up, the
    bridge, is a call too). One bridge only: a frame bridges once every call is applied (MapWorker.drained); with
    idle() a warm-up call that ended between a frame's sync and its submission made it a second bridge (12 counts
    of 10 frames under load)."""
    from slam.run.runner import run_to_folder

    _simulated(monkeypatch, 0.0)
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=10", "parallel=true",
                                    "mapper_process=true", "data.realtime=true", "mapping.every_frame=1"],
                      profile="quality")
    m = run_to_folder(cfg, tmp_path / "rt", progress=False, mesh=False)
    assert m["num_frames"] == 10 and m["realtime"]["frames_dropped"] == 0
    odometry = m["frames_odometry"]
    assert odometry == sum(1 for e in m["events"] if e.get("odometry"))
    # a frame the guard did not trust is not mapped either (which map a frame meets depends on the mapper's timing)
    counts = (m["mapping_calls"], m["mapping_declined"], odometry, m["frames_lost"])
    assert m["mapping_calls"] >= 1 and 10 <= sum(counts) <= 11, (counts, m["events"])
    assert m["ate_rmse_m"] < 0.05
