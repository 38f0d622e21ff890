"""``lrslam live`` (slam/data/live.py, slam/run/live.py) on a stand-in camera that serves the tiny room at 30 Hz:
the loop takes the newest frame each time it is free, Ctrl-C stops the camera and every output is written, a camera
that fails mid-run ends the run with what it has, and the frames received are recorded as a TUM folder that
``lrslam run`` reads back."""

import json
import os
import signal
import time

import numpy as np
import pytest

from slam.config import load_config
from slam.engine.observers import Observer
from tests.slam.conftest import TINY


class FakeCamera:
    """Serves the tiny room's frames at ``rate`` Hz in real time (cycling when ``frames`` exceeds them), depth in
    millimetres; ``fail_at``: raises as an unplugged camera does on that frame."""

    def __init__(self, seq, frames=24, rate=30.0, fail_at=None):
        from slam.data.replica import ReplicaDataset

        self.src = ReplicaDataset(seq, undistort=False)
        self.frames, self.rate, self.fail_at = frames, rate, fail_at
        self.i, self.t0, self.closed = 0, None, False

    def open(self):
        return self.src.intrinsics, None, 1000.0

    def image(self, i):
        f = self.src[i % len(self.src)]
        rgb = (f.color.numpy() * 255).round().astype(np.uint8)
        return rgb, (f.depth.numpy() * 1000).round().astype(np.uint16)

    def read(self):
        if self.i >= self.frames:
            return None
        if self.i == self.fail_at:
            raise RuntimeError("device disconnected (made so by the test)")
        self.t0 = time.perf_counter() if self.t0 is None else self.t0
        wait = self.t0 + self.i / self.rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        self.i += 1
        return (1000.0 + (self.i - 1) / self.rate, *self.image(self.i - 1))

    def close(self):
        self.closed = True


def _cfg(*extra):
    return load_config("synthetic", [*TINY[1:], "parallel=true", "data.realtime=true", *extra], profile="quality")


def _rows(path):
    return [ln.split()[0] for ln in path.read_text().splitlines() if not ln.startswith("#")]


def test_a_live_run_takes_the_newest_frames_and_records_every_one(tiny_seq, tmp_path):
    from slam.data import TUMDataset
    from slam.data.live import LiveFeed
    from slam.run.live import live_to_folder

    cam = FakeCamera(tiny_seq, frames=90)  # 3 s: the frames of the system's start-up are missed, as live
    feed = LiveFeed(cam, record=tmp_path / "frames")
    m = live_to_folder(_cfg(), feed, tmp_path / "out", progress=False, mesh=False)
    rt = m["realtime"]
    assert m["frames_received"] == 90 and rt["frames_processed"] + rt["frames_dropped"] == 90
    assert rt["frames_processed"] >= 2 and rt["latency_median_s"] > 0 and cam.closed
    rows = _rows(tmp_path / "out" / "trajectory.txt")
    assert len(rows) == rt["frames_processed"] == m["num_frames"]
    taken = [int(r.split(",")[1]) for r in (tmp_path / "out" / "frames.csv").read_text().splitlines()[1:]]
    assert taken == sorted(set(taken)) and taken[-1] == 89  # the last frame is always taken
    assert [float(r) for r in rows] == pytest.approx([1000.0 + i / 30 for i in taken])  # the camera's clock
    rec = TUMDataset(tmp_path / "frames", undistort=False)
    assert len(rec) == 90
    rgb, depth = cam.image(5)
    assert np.array_equal((rec[5].color.numpy() * 255).round().astype(np.uint8), rgb)
    assert np.allclose(rec[5].depth.numpy(), depth / 1000.0)
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["realtime"] == rt


class _SigintAfter(Observer):
    def __init__(self, n):
        self.n = n

    def on_frame(self, run, rec):
        if rec.k + 1 == self.n:
            os.kill(os.getpid(), signal.SIGINT)


def test_ctrl_c_stops_the_camera_and_writes_every_output(tiny_seq, tmp_path):
    from slam.data.live import LiveFeed
    from slam.run.live import live_to_folder

    cam = FakeCamera(tiny_seq, frames=10**6)  # a camera that would go on for ever
    feed = LiveFeed(cam, record=None)
    m = live_to_folder(_cfg(), feed, tmp_path / "out", progress=False, mesh=True, observers=[_SigintAfter(4)])
    # the newest frame that arrived before the stop may still be taken after the fourth
    assert 4 <= m["realtime"]["frames_processed"] <= 5 and cam.closed and not m.get("partial")
    rows = _rows(tmp_path / "out" / "trajectory.txt")
    assert (tmp_path / "out" / "mesh.ply").stat().st_size > 0 and len(rows) == m["realtime"]["frames_processed"]


def test_a_camera_that_fails_mid_run_ends_it_with_what_it_has(tiny_seq, tmp_path):
    from slam.data.live import LiveFeed
    from slam.run.live import live_to_folder

    feed = LiveFeed(FakeCamera(tiny_seq, frames=24, fail_at=9), record=tmp_path / "frames")
    m = live_to_folder(_cfg(), feed, tmp_path / "out", progress=False, mesh=False)
    assert m["frames_received"] == 9 and "device disconnected" in m["camera_error"]
    assert 1 <= m["realtime"]["frames_processed"] <= 9
    assert (tmp_path / "frames" / "rgb.txt").read_text().count("\n") >= 9  # the recording is finished too


def test_lrslam_live_runs_a_camera_from_the_command_line(tiny_seq, tmp_path, monkeypatch, capsys):
    import slam.commands.live as live_cmd
    from slam.cli import main

    monkeypatch.setitem(live_cmd.CAMERAS, "fake", lambda args: FakeCamera(tiny_seq, frames=8))
    out = tmp_path / "out"
    assert main(["live", "--camera", "fake", "--config", "synthetic", "--out", str(out), "--no-mesh", "--quiet",
                 *TINY[1:]]) == 0
    said = capsys.readouterr().out
    assert '"frames_received": 8' in said and f"lrslam run --data {out / 'frames'}" in said
    assert (out / "frames" / "rgb.txt").exists() and (out / "trajectory.txt").exists()
    assert main(["live", "--camera", "fake", "--out", str(out), "--max-frames", "0"]) == 2


def test_lrslam_live_logs_the_run_to_rerun_as_it_goes(tiny_seq, tmp_path, monkeypatch, capsys):
    """``lrslam live --rerun FILE`` (as ``--rerun-connect`` streams): the camera pose of every frame processed, equal
    to the written trajectory, and its images."""
    pytest.importorskip("rerun")
    import slam.commands.live as live_cmd
    from slam.cli import main
    from tests.slam.run.test_viewer import read_recording

    monkeypatch.setitem(live_cmd.CAMERAS, "fake", lambda args: FakeCamera(tiny_seq, frames=8))
    out, rrd = tmp_path / "out", tmp_path / "live.rrd"
    assert main(["live", "--camera", "fake", "--config", "synthetic", "--out", str(out), "--no-mesh", "--quiet",
                 "--rerun", str(rrd), *TINY[1:]]) == 0
    assert "Rerun recording" in capsys.readouterr().out or rrd.exists()
    data = read_recording(rrd)
    est = np.atleast_2d(np.loadtxt(out / "trajectory.txt"))[:, 1:4]
    cam = data["/world/camera"]["Transform3D:translation"]
    assert len(cam) == len(est) >= 1
    np.testing.assert_allclose([v[0] for _, v in cam], est, atol=1e-5)
    assert {"/world/camera/image/rgb", "/world/camera/image/depth", "/world/trajectory/estimated"} <= set(data)
