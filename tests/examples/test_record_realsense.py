"""examples/record_realsense.py against a stand-in for pyrealsense2 (no camera here): the recording it writes
loads with the camera the device reported."""

import importlib.util
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from slam.data import Intrinsics, TUMDataset

SCRIPT = Path(__file__).resolve().parents[2] / "examples" / "record_realsense.py"


def _load_script():
    spec = importlib.util.spec_from_file_location("record_realsense", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fake_rs(n_frames=40, model="brown_conrady", coeffs=(0.1, -0.2, 0.001, 0.002, 0.03)):
    """The part of pyrealsense2's API the script uses; frames at 30 Hz, depth 1.25 m in 1 mm units."""
    rs = types.SimpleNamespace()
    rs.stream = types.SimpleNamespace(depth="depth", color="color")
    rs.format = types.SimpleNamespace(z16="z16", rgb8="rgb8")
    rs.distortion = types.SimpleNamespace(brown_conrady="brown_conrady", inverse_brown_conrady="inverse_brown_conrady")
    intr = types.SimpleNamespace(fx=61.5, fy=61.25, ppx=31.75, ppy=23.5, width=64, height=48, model=model,
                                 coeffs=list(coeffs))
    profile_of = types.SimpleNamespace(as_video_stream_profile=lambda: types.SimpleNamespace(
        get_intrinsics=lambda: intr))
    sensor = types.SimpleNamespace(get_depth_scale=lambda: 0.001)
    profile = types.SimpleNamespace(get_device=lambda: types.SimpleNamespace(first_depth_sensor=lambda: sensor),
                                    get_stream=lambda s: profile_of)

    class Frame:
        def __init__(self, data, t):
            self.data, self.t = data, t

        def __bool__(self):
            return True

        def get_data(self):
            return self.data

        def get_timestamp(self):
            return self.t

    class FrameSet:
        def __init__(self, i):
            t = 1.7e12 + i * 1000 / 30  # ms, the device's global clock
            self.color = Frame(np.full((48, 64, 3), i, np.uint8), t)
            self.depth = Frame(np.full((48, 64), 1250, np.uint16), t + 2.0)

        def get_color_frame(self):
            return self.color

        def get_depth_frame(self):
            return self.depth

    class Pipeline:
        def __init__(self):
            self.i, self.started = 0, False

        def start(self, config):
            assert config.streams == [("depth", 64, 48, "z16", 30), ("color", 64, 48, "rgb8", 30)]
            self.started = True
            return profile

        def wait_for_frames(self):
            if self.i >= n_frames:
                raise KeyboardInterrupt  # the user stops the recording
            self.i += 1
            return FrameSet(self.i - 1)

        def stop(self):
            self.started = False

    class Config:
        def __init__(self):
            self.streams = []

        def enable_stream(self, *args):
            self.streams.append(args)

    rs.pipeline, rs.config = Pipeline, Config
    rs.align = lambda to: types.SimpleNamespace(process=lambda fs: fs)
    return rs


def test_recording_loads_with_the_device_camera(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", _fake_rs())
    script = _load_script()
    out = tmp_path / "desk"
    assert script.main(["--out", str(out), "--frames", "5", "--width", "64", "--height", "48", "--warmup", "3"]) == 0
    ds = TUMDataset(out)
    assert len(ds) == 5 and ds.camera == "file"
    assert ds.raw_intrinsics == Intrinsics(61.5, 61.25, 31.75, 23.5, 48, 64)
    assert ds.distortion == (0.1, -0.2, 0.001, 0.002, 0.03) and ds.depth_scale == 1000.0
    f = ds[2]
    assert float(f.depth[24, 32]) == pytest.approx(1.25)
    assert f.timestamp == pytest.approx(1.7e9 + 5 / 30, abs=1e-6)  # frames 0-2 were the warm-up
    assert not bool(ds.valid_poses.any())


def test_ctrl_c_keeps_the_frames_and_inverse_distortion_is_not_written(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyrealsense2", _fake_rs(n_frames=7, model="inverse_brown_conrady"))
    out = tmp_path / "short"
    assert _load_script().main(["--out", str(out), "--width", "64", "--height", "48", "--warmup", "2"]) == 0
    assert "inverse_brown_conrady distortion" in capsys.readouterr().err
    ds = TUMDataset(out)
    assert len(ds) == 5 and ds.distortion is None


def test_without_pyrealsense2_one_line_and_exit_2(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    assert _load_script().main(["--out", "never"]) == 2
    assert capsys.readouterr().err == ('record_realsense: error: pyrealsense2 is not installed: '
                                       'python3 -m pip install -e ".[realsense]"\n')
