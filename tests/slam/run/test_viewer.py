"""The Rerun viewer: a short run's recording read back with rerun's own reader, and the CLI's bad input."""

import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from slam.config import load_config

from tests.slam.conftest import TINY

# a coarse, unevaluated mesh: the recording's mesh entity without the seconds of reconstruction metrics
CHEAP_MESH = ["meshing.resolution=0.08", "evaluation.icp=false", "evaluation.samples=2000",
              "evaluation.depth_l1_views=2"]


def read_recording(path) -> dict:
    """``{entity: {component column: [(frame or None, instances), ...]}}`` from an .rrd file, via rerun's reader
    (each logged row holds a list of instances: one translation, one strip, every vertex of a mesh)."""
    rr = pytest.importorskip("rerun")
    if not hasattr(rr, "chunk") or not hasattr(rr.chunk, "RrdReader"):
        pytest.skip(f"rerun-sdk {rr.__version__} has no rerun.chunk.RrdReader")
    data: dict = defaultdict(lambda: defaultdict(list))
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        cols = {n: batch.column(n).to_pylist() for n in batch.schema.names if not n.startswith("rerun.controls")}
        frames = cols.pop("frame", [None] * batch.num_rows)
        cols.pop("log_time", None)
        for name, values in cols.items():
            for f, v in zip(frames, values):
                if v is not None:
                    data[chunk.entity_path][name].append((f, v))
    for comps in data.values():
        for name in comps:
            comps[name].sort(key=lambda fv: -1 if fv[0] is None else fv[0])
    return data


@pytest.mark.slow
def test_recording_of_a_short_run(tiny_seq, tmp_path):
    pytest.importorskip("rerun")
    import trimesh

    from slam.run.runner import run_to_folder
    from slam.run.viewer import RerunObserver

    # sequential: the preview meshes follow keyframes as they are added, which a parallel mapper does later
    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, *CHEAP_MESH, "parallel=false"], profile="quality")
    rrd = tmp_path / "rec" / "run.rrd"
    rrd.parent.mkdir()
    previews = tmp_path / "rec" / "previews.rrd"
    obs = RerunObserver(save=rrd, images_every=2)
    metrics = run_to_folder(cfg, tmp_path / "run", progress=False, mesh=True,
                            observers=[obs, RerunObserver(save=previews, mesh_every=1)])
    assert 0 < obs.log_s < metrics["loop_s"]
    data = read_recording(rrd)
    n = metrics["num_frames"]
    frames = list(range(n))
    assert {"/world", "/world/camera", "/world/camera/image", "/world/camera/image/rgb", "/world/camera/image/depth",
            "/world/trajectory/estimated", "/world/trajectory/ground_truth", "/world/mesh", "/metrics/ate_cm",
            "/metrics/frame_time_s"} <= set(data)

    # the frustum: OpenCV intrinsics of the 60x80 sequence, static
    pin = data["/world/camera/image"]
    assert pin["Pinhole:resolution"] == [(None, [[80.0, 60.0]])]
    K = np.array(pin["Pinhole:image_from_camera"][0][1][0]).reshape(3, 3).T  # stored column-major
    assert K[0, 0] == pytest.approx(48.0) and K[0, 2] == pytest.approx(39.5) and K[1, 2] == pytest.approx(29.5)

    # the camera pose every frame, equal to the written trajectory
    est = np.loadtxt(tmp_path / "run" / "trajectory.txt")[:, 1:4]
    cam = data["/world/camera"]["Transform3D:translation"]
    assert [f for f, _ in cam] == frames
    np.testing.assert_allclose([v[0] for _, v in cam], est, atol=1e-5)

    # trajectories grow by one point a frame; the last strip is the whole trajectory
    strips = data["/world/trajectory/estimated"]["LineStrips3D:strips"]
    assert [f for f, _ in strips] == frames and [len(v[0]) for _, v in strips] == list(range(1, n + 1))
    np.testing.assert_allclose(strips[-1][1][0], est, atol=1e-5)
    gt = np.loadtxt(tmp_path / "run" / "trajectory_gt.txt")[:, 1:4]
    np.testing.assert_allclose(data["/world/trajectory/ground_truth"]["LineStrips3D:strips"][-1][1][0], gt, atol=1e-5)

    # images every 2nd frame: colour uint8 RGB, depth uint16 millimetres matching the sequence's depth
    rgb = data["/world/camera/image/rgb"]
    assert [f for f, _ in rgb["Image:buffer"]] == frames[::2]
    assert len(rgb["Image:buffer"][0][1][0]) == 60 * 80 * 3
    depth = data["/world/camera/image/depth"]
    assert depth["DepthImage:meter"][0][1] == [1000.0]
    mm = np.frombuffer(bytes(depth["DepthImage:buffer"][0][1][0]), dtype=np.uint16).reshape(60, 80)
    from slam.engine.setup import load_data

    true_depth = np.asarray(load_data(cfg)[0].depth)
    np.testing.assert_allclose(mm / 1000.0, true_depth, atol=6e-4)

    # scalars: live ATE from the third frame on, its last value the run's ATE; a frame time every frame
    ate = data["/metrics/ate_cm"]["Scalars:scalars"]
    assert [f for f, _ in ate] == frames[2:]
    assert ate[-1][1][0] == pytest.approx(100 * metrics["ate_rmse_m"], rel=1e-6)
    ft = data["/metrics/frame_time_s"]["Scalars:scalars"]
    assert [f for f, _ in ft] == frames and all(v[0] > 0 for _, v in ft)
    # the scene's size every frame (as in frames.csv), and its box once (this box does not grow)
    params = data["/metrics/parameters"]["Scalars:scalars"]
    assert [f for f, _ in params] == frames and params[-1][1][0] == metrics["parameters"]["total"]
    assert [f for f, _ in data["/metrics/field_bytes"]["Scalars:scalars"]] == frames
    box = data["/world/scene_box"]
    assert [f for f, _ in box["Boxes3D:half_sizes"]] == [0]

    # the final mesh, with a colour per vertex
    mesh = trimesh.load(tmp_path / "run" / "mesh.ply", process=False)
    logged = data["/world/mesh"]
    assert len(logged["Mesh3D:vertex_positions"][0][1]) == len(mesh.vertices) > 0
    assert len(logged["Mesh3D:triangle_indices"][0][1]) == len(mesh.faces)
    assert len(logged["Mesh3D:vertex_colors"][0][1]) == len(mesh.vertices)
    assert logged["Mesh3D:vertex_positions"][0][0] == frames[-1]

    # a second observer with a preview mesh after every keyframe (frames 0 and 4 here), then the final one
    meshes = read_recording(previews)["/world/mesh"]["Mesh3D:vertex_positions"]
    from slam.engine.setup import frame_indices

    keyframes = [k for k in frame_indices(24, cfg)
                 if k % cfg.mapping.every_frame == 0 and k % cfg.mapping.keyframe_every == 0]
    assert [f for f, _ in meshes] == keyframes + [frames[-1]]
    assert all(len(v) > 0 for _, v in meshes)


@pytest.mark.slow
def test_rerun_connect_streams_to_a_listening_viewer(tiny_seq, tmp_path):
    """--rerun-connect against a real listener: Rerun's own `rerun --port P --save FILE` (no window)."""
    pytest.importorskip("rerun")
    import socket
    import subprocess
    import time
    import warnings

    from slam.cli import main

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    saved = tmp_path / "received.rrd"
    # the viewer binary itself: `python -m rerun` would leave it running as an orphan on terminate()
    rerun_cli = pytest.importorskip("rerun_cli")
    binary = Path(rerun_cli.__file__).parent / "rerun"
    server = subprocess.Popen([str(binary), "--port", str(port), "--save", str(saved)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):  # until it listens
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.1)
        assert main(["run", "--data", str(tiny_seq), "--out", str(tmp_path / "run"), "--no-mesh", "--quiet",
                     "--rerun-connect", f"rerun+http://127.0.0.1:{port}/proxy", *TINY]) == 0
        time.sleep(1.0)  # the listener writes what it received
    finally:
        server.terminate()
        server.wait(timeout=10)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stream saved by a listener has no footer
        data = read_recording(saved)
    strips = data["/world/trajectory/estimated"]["LineStrips3D:strips"]
    assert [f for f, _ in strips] == list(range(6)) and len(strips[-1][1][0]) == 6
    assert "/world/camera/image/rgb" in data and "/metrics/frame_time_s" in data


def test_resumed_run_continues_the_trajectories(tiny_seq, tmp_path):
    pytest.importorskip("rerun")
    import os
    import signal

    from slam.engine.observers import Observer
    from slam.run.runner import RunInterrupted, run_to_folder
    from slam.run.viewer import RerunObserver

    class Interrupt(Observer):
        def on_frame(self, run, record):
            if record.k == 2:
                os.kill(os.getpid(), signal.SIGINT)

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY], profile="quality")
    with pytest.raises(RunInterrupted):
        run_to_folder(cfg, tmp_path / "run", progress=False, mesh=False, observers=[Interrupt()])
    rrd = tmp_path / "resumed.rrd"
    run_to_folder(cfg, tmp_path / "run", progress=False, mesh=False, resume=True, observers=[RerunObserver(save=rrd)])
    strips = read_recording(rrd)["/world/trajectory/estimated"]["LineStrips3D:strips"]
    assert [f for f, _ in strips] == [3, 4, 5] and [len(v[0]) for _, v in strips] == [4, 5, 6]
    est = np.loadtxt(tmp_path / "run" / "trajectory.txt")[:, 1:4]
    np.testing.assert_allclose(strips[-1][1][0], est, atol=1e-5)


def test_cli_rerun_into_unwritable_path_exits_2_before_the_run(tmp_path, capsys, monkeypatch):
    pytest.importorskip("rerun")
    import slam.run.runner
    from slam.cli import main

    def no_run(*a, **k):
        raise AssertionError("the run must not start")

    monkeypatch.setattr(slam.run.runner, "run_to_folder", no_run)
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for target, why in ((blocker / "run.rrd", "is a file, not a folder"), (tmp_path, "is a folder")):
        assert main(["run", "--rerun", str(target), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("lrslam run: error: --rerun") and why in err
    assert not (tmp_path / "o").exists()


def test_cli_without_rerun_names_the_install_command(tmp_path, capsys, monkeypatch):
    from slam.cli import main

    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun -> ImportError
    assert main(["run", "--rerun", str(tmp_path / "x.rrd"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install "rerun-sdk>=0.24"' in err and '[viewer]' in err
    assert not (tmp_path / "x.rrd").exists()


def test_observer_rejects_bad_options(tmp_path):
    pytest.importorskip("rerun")
    from slam.errors import SlamInputError
    from slam.run.viewer import RerunObserver

    with pytest.raises(SlamInputError, match="needs a recording file"):
        RerunObserver()
    with pytest.raises(SlamInputError, match="--rerun-images-every must be >= 1"):
        RerunObserver(save=tmp_path / "x.rrd", images_every=0)
    with pytest.raises(SlamInputError, match="--rerun-jpeg must be in 1..100"):
        RerunObserver(save=tmp_path / "x.rrd", jpeg_quality=0)


def test_up_axis_follows_the_first_camera():
    rr = pytest.importorskip("rerun")
    import torch

    from slam.run.viewer import _up_axis

    assert _up_axis(torch.eye(4)) == rr.ViewCoordinates.RIGHT_HAND_Y_DOWN  # TUM: the first camera is the world
    level = torch.eye(4)
    level[:3, :3] = torch.tensor([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # camera y (down) = world -z
    assert _up_axis(level) == rr.ViewCoordinates.RIGHT_HAND_Z_UP


def test_loop_closure_shows_the_corrected_trajectory_and_the_loops(tiny_seq, tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("gtsam")
    from slam.run.runner import run_to_folder
    from slam.run.viewer import RerunObserver
    from tests.slam.loop.test_run_loops import LOOPS

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, *LOOPS])
    rrd = tmp_path / "run.rrd"
    metrics = run_to_folder(cfg, tmp_path / "run", progress=False, mesh=False, observers=[RerunObserver(save=rrd)])
    data = read_recording(rrd)
    corrected = data["/world/trajectory/corrected"]["LineStrips3D:strips"][-1][1][0]
    np.testing.assert_allclose(corrected, np.loadtxt(tmp_path / "run" / "trajectory.txt")[:, 1:4], atol=1e-5)
    edges = data["/world/loops"]["LineStrips3D:strips"][-1][1]
    assert len(edges) == metrics["loops"]["loops"] >= 3
