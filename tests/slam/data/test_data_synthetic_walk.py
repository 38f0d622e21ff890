"""The synthetic walk: its path, its sensor-like depth, a 200-frame excerpt on disk and a short run of its preset."""

import json
import time

import numpy as np
import pytest

from slam.cli import main
from slam.data import ReplicaDataset, load_dataset
from slam.data.synthetic import (
    WALK_FRAMES,
    build_walk_scene,
    free_space_distance,
    walk_config,
    walk_path,
    walk_sequence,
)
from slam.data.synthetic.render import render_frame
from slam.data.synthetic.scene import cast_rays

EXCERPT = 200
# a few frames of the preset with tiny-like settings (tests/slam/conftest.py's TINY); a box from the median depth
# with no margin, so that it grows within these frames
RUN = ["data.max_frames=5", "tracking.iters=3", "tracking.pixels=100", "mapping.iters=3", "mapping.iters_first=5",
       "mapping.pixels=200", "rendering.n_stratified=8", "rendering.n_importance=4", "scene.bound_auto_percentile=50",
       "scene.bound_auto_margin=0", "evaluation.samples=2000", "evaluation.depth_l1_views=0", "meshing.resolution=0.08"]


@pytest.fixture(scope="module")
def walk_poses():
    return walk_path(walk_config())


@pytest.fixture(scope="module")
def excerpt(tmp_path_factory):
    """The walk's first 200 frames, generated into a fresh cache; with the seconds it took."""
    t0 = time.perf_counter()
    path = walk_sequence(EXCERPT, cache_dir=tmp_path_factory.mktemp("walk_cache"))
    return path, time.perf_counter() - t0


@pytest.fixture(scope="module")
def preset_run(tmp_path_factory):
    """``lrslam run --config synthetic/walk`` on its first frames, generating them into an empty cache."""
    cache, out = tmp_path_factory.mktemp("run_cache"), tmp_path_factory.mktemp("walk_run") / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("LRSLAM_CACHE", str(cache))
        assert main(["run", "--config", "synthetic/walk", "--profile", "quality", "--out", str(out), *RUN]) == 0
    return out, cache


def test_walk_length_speed_and_rotation(walk_poses):
    t = walk_poses[:, :3, 3]
    step = np.linalg.norm(np.diff(t, axis=0), axis=1)
    assert len(walk_poses) == WALK_FRAMES >= 2000
    assert 38.0 < step.sum() < 42.0 and np.ptp(t[:, 0]) > 18.0  # through three rooms along 20 m and back
    speed = step * 30.0
    assert 0.5 < speed.mean() < 0.7 and speed.min() > 0.4 and speed.max() < 1.0
    rel = np.einsum("nji,njk->nik", walk_poses[:-1, :3, :3], walk_poses[1:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert ang.mean() < 1.0 and ang.max() < 3.0  # gentle head rotation, the half turns included
    assert np.linalg.norm(t[-1] - t[0]) < 0.1  # the walk ends where it began
    r = walk_poses[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)


def test_walk_stays_in_free_space(walk_poses):
    scene = build_walk_scene(0)
    centres = walk_poses[:, :3, 3]
    assert free_space_distance(scene, centres).min() > 0.4
    # and by ray casting: from every 10th camera centre, no surface within 0.4 m in 26 directions
    g = np.stack(np.meshgrid(*[[-1.0, 0.0, 1.0]] * 3, indexing="ij"), -1).reshape(-1, 3)
    dirs = g[np.any(g != 0, axis=1)]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for c in centres[::10]:
        t, _, _ = cast_rays(scene, c, dirs)
        assert t.min() > 0.4


def test_depth_noise_follows_the_sensor_model(excerpt):
    ds = ReplicaDataset(excerpt[0])
    scene, intr = build_walk_scene(0), ds.intrinsics
    exact, measured, cosines = [], [], []
    for i in range(0, EXCERPT, 20):
        _, depth, cos, _ = render_frame(scene, ds.gt_poses[i].double().numpy(), intr)
        exact.append(depth), measured.append(ds[i].depth.numpy()), cosines.append(cos)
    z, m, cos = (np.concatenate([a.reshape(-1) for a in x]) for x in (exact, measured, cosines))
    valid = m > 0
    assert not valid[(z < 0.4) | (z > 4.5) | (cos < 0.12)].any()  # range and grazing-angle dropouts
    assert 0.6 < valid.mean() < 0.9
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    for lo in (1.0, 2.0, 3.0, 4.0):
        sel = valid & (z > lo - 0.25) & (z < lo + 0.25)
        assert sel.sum() > 2000, lo
        ratio = (m[sel] - z[sel]) / sigma[sel]
        assert abs(ratio.mean()) < 0.1 and 0.9 < ratio.std() < 1.1, (lo, ratio.mean(), ratio.std())


def test_excerpt_loads_and_is_fast(excerpt):
    path, seconds = excerpt
    assert seconds < 60.0  # about 7 s on the 2-core box (docs/data.md)
    ds = load_dataset(path)
    assert isinstance(ds, ReplicaDataset) and len(ds) == EXCERPT and ds.name
    assert (ds.intrinsics.height, ds.intrinsics.width) == (120, 160)
    assert ds.gt_mesh_path == path / "mesh.ply"
    np.testing.assert_allclose(ds.gt_poses.numpy(), walk_path(walk_config(EXCERPT)).astype(np.float32), atol=1e-6)
    f = ds[EXCERPT - 1]
    assert f.timestamp == pytest.approx((EXCERPT - 1) / 30) and float(f.depth.max()) < 4.6
    assert json.loads((path / "synth.json").read_text())["config"]["scene"] == "walk"


def test_preset_runs_generates_and_grows(preset_run, excerpt):
    out, cache = preset_run
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["num_frames"] == 5 and metrics["ate_rmse_m"] < 0.05
    assert any("growth" in e for e in metrics["events"])
    (made,) = [p for p in cache.iterdir() if p.name.startswith("synthetic_walk_")]
    # deterministic: the run's 5-frame excerpt holds the same bytes as the 200-frame one's first frames
    for name in ("results/frame000004.png", "results/depth000004.png"):
        assert (made / name).read_bytes() == (excerpt[0] / name).read_bytes()
    lines = (made / "traj.txt").read_text().splitlines()
    assert lines == (excerpt[0] / "traj.txt").read_text().splitlines()[:5]


def test_synth_command_chooses_the_scene(tmp_path, capsys):
    assert main(["synth", "--scene", "walk", "--out", str(tmp_path / "w"), "--frames", "2", "--height", "24",
                 "--width", "32"]) == 0
    assert "wrote 2 frames 24x32" in capsys.readouterr().out
    cfg = json.loads((tmp_path / "w" / "synth.json").read_text())["config"]
    assert (cfg["scene"], cfg["sensor_holes"], cfg["loop_frames"]) == ("walk", True, WALK_FRAMES)
    with pytest.raises(SystemExit) as exc:  # argparse refuses it, listing room and walk
        main(["synth", "--scene", "hall", "--out", str(tmp_path / "h")])
    assert exc.value.code == 2 and "choose from 'room', 'walk'" in capsys.readouterr().err


def test_unknown_synthetic_scene_is_refused(capsys):
    assert main(["run", "--config", "synthetic/walk", "data.options.scene=hall"]) == 2
    assert "'data.options.scene' = 'hall': must be one of room, walk" in capsys.readouterr().err
