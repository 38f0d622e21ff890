"""benchmarks/_gt_timing.py (profile_targets.py --loops): the time offset is recovered from a trajectory whose images were exposed 20 ms
before their timestamps, and a loop's error is measured at each clock."""

import numpy as np
from scipy.spatial.transform import Rotation

from slam.eval.trajectory import poses_from_tum
from tests.benchmarks.conftest import script_on_path


def _rows(t: np.ndarray) -> np.ndarray:
    """TUM rows of a camera turning about a wobbling axis at tens of degrees a second while it moves."""
    rv = np.stack((0.6 * np.sin(2.0 * t), 1.0 * np.sin(1.3 * t + 0.4), 0.3 * t), -1)
    xyz = np.stack((0.2 * np.sin(t), 0.1 * t, 0.05 * np.cos(3 * t)), -1)
    return np.concatenate((t[:, None], xyz, Rotation.from_rotvec(rv).as_quat()), 1)


def test_the_offset_that_fits_the_tracker_is_the_exposure_delay():
    with script_on_path("_gt_timing") as bench:
        t_gt = np.arange(0.0, 8.0, 0.01)  # motion capture at 100 Hz
        truth = bench.Truth(_rows(t_gt))
        t_img = np.arange(0.5, 7.5, 1 / 30)
        est = poses_from_tum(_rows(t_img - 0.020)[:, 1:8])  # each image shows the pose 20 ms before its stamp
        delta, curve = bench.fit_offset(est, t_img, truth, span=5, grid_ms=40, step_ms=2.5)
        assert delta == -0.020
        assert min(c["median_deg"] for c in curve) < 0.01 < max(c["median_deg"] for c in curve)
        # a loop measured exactly between two such images: wrong by the delay at offset 0, right at the fitted one
        q, c = 150, 20
        rel = np.linalg.inv(est[c]) @ est[q]
        loop = {"query": q, "match": c, "relative_pose": rel.tolist()}
        row = bench.loop_errors([loop], t_img, t_img + 0.01, truth, delta)[0]
    assert row["fitted_offset"]["deg"] < 0.01 and row["fitted_offset"]["m"] < 1e-4
    assert row["offset_0"]["deg"] > 0.5
    assert 10 < row["angular_speed_deg_s"][0] < 120


def test_the_tum_folder_of_run_arguments_and_the_worst_loop(tmp_path):
    tum = tmp_path / "seq"
    tum.mkdir()
    (tum / "groundtruth.txt").write_text("# t x y z qx qy qz qw\n")
    (tum / "depth.txt").write_text("")
    with script_on_path("_gt_timing") as bench:
        assert bench.tum_folder(["--no-mesh", f"--data={tum}", "seed=1"]) == tum
        assert bench.tum_folder([f"--data={tmp_path}"]) is None  # no ground truth: a synthetic or a user's folder
        assert bench.tum_folder(["--config", "synthetic"]) is None
        runs = [{"loops": [{"fitted_offset": {"m": 0.01, "deg": 2.5}}, {"fitted_offset": {"m": 0.03, "deg": 1.0}}]},
                {"loops": []}]
        assert bench.worst(runs, "fitted_offset") == [0.03, 2.5]
        assert bench.worst([{"loops": []}], "fitted_offset") is None
