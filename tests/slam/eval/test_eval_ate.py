import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from slam.errors import SlamInputError
from slam.eval import associate, ate, ate_from_files, read_tum_trajectory, write_tum_trajectory


def _random_traj(n=60, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0)
    rot = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0)).as_matrix()
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = t
    return poses


def _rigid(rotvec, t):
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    m[:3, 3] = t
    return m


def test_rigidly_moved_trajectory_has_zero_ate_after_alignment():
    gt = _random_traj()
    est = _rigid([0.3, -0.2, 1.0], [1.0, 2.0, -0.5]) @ gt
    res = ate(est, gt)
    assert res.rmse < 1e-9
    # without alignment the error is the full displacement
    assert ate(est, gt, align="none").min > 0.1


def test_constant_offset_without_alignment_equals_offset():
    gt = _random_traj()
    est = gt.copy()
    est[:, :3, 3] += np.array([0.03, 0.0, 0.04])  # 5 cm
    res = ate(est, gt, align="none")
    np.testing.assert_allclose(res.errors, 0.05, atol=1e-12)
    assert res.rmse == pytest.approx(0.05) and res.max == pytest.approx(0.05) and res.std == pytest.approx(0.0)
    # a pure translation offset is removed by rigid alignment
    assert ate(est, gt).rmse < 1e-12


def test_known_noise_statistics_and_sim3():
    # two-point alternating error of +-1 cm along x on a straight-ish path: after rigid alignment the mean
    # translation is zero, so each error stays 1 cm
    gt = np.zeros((40, 3))
    gt[:, 0] = np.linspace(0, 2, 40)
    gt[:, 1] = np.sin(np.linspace(0, 3, 40))
    est = gt.copy()
    est[:, 2] += np.where(np.arange(40) % 2 == 0, 0.01, -0.01)
    res = ate(est, gt, align="none")
    assert res.rmse == pytest.approx(0.01) and res.median == pytest.approx(0.01)
    scaled = 2.5 * gt
    assert ate(scaled, gt, align="sim3").rmse < 1e-9
    assert ate(scaled, gt, align="sim3").scale == pytest.approx(0.4)
    assert ate(scaled, gt, align="rigid").rmse > 0.1


def test_torch_input_and_nan_frames_are_dropped():
    gt = _random_traj(30)
    est = torch.tensor(gt, dtype=torch.float32)
    gt_nan = gt.copy()
    gt_nan[5] = np.nan
    res = ate(est, gt_nan)
    assert res.n == 29 and not res.used[5]
    assert res.rmse < 1e-6


def test_bad_shapes_raise():
    with pytest.raises(SlamInputError, match="30 estimated poses but 29"):
        ate(_random_traj(30), _random_traj(29))
    with pytest.raises(SlamInputError, match="align"):
        ate(_random_traj(5), _random_traj(5), align="scale")


def test_matches_evo_ape(tmp_path):
    evo_traj = pytest.importorskip("evo.core.trajectory")
    from evo.core import metrics
    from evo.tools import file_interface

    gt = _random_traj(80, seed=1)
    rng = np.random.default_rng(2)
    est = _rigid([0.1, 0.2, -0.3], [0.5, -1.0, 0.2]) @ gt
    est[:, :3, 3] += rng.normal(0, 0.01, (80, 3))
    ts = 1305031233.0 + np.arange(80) / 30.0
    pe, pg = tmp_path / "est.txt", tmp_path / "gt.txt"
    write_tum_trajectory(pe, ts, est)
    write_tum_trajectory(pg, ts, gt)

    ours, _ = ate_from_files(pe, pg)
    ref = file_interface.read_tum_trajectory_file(str(pg))
    est_t = file_interface.read_tum_trajectory_file(str(pe))
    assert isinstance(est_t, evo_traj.PoseTrajectory3D)
    est_t.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est_t))
    stats = ape.get_all_statistics()
    for key in ("rmse", "mean", "median", "std", "max", "min"):
        assert getattr(ours, key) == pytest.approx(stats[key], abs=1e-6), key
    assert 0.005 < ours.rmse < 0.03


def test_tum_roundtrip_and_evo_reads_ours(tmp_path):
    from evo.tools import file_interface

    poses = _random_traj(10)
    ts = np.arange(10) * 0.1 + 100.0
    path = write_tum_trajectory(tmp_path / "t.txt", ts, torch.tensor(poses))
    ts2, poses2 = read_tum_trajectory(path)
    np.testing.assert_allclose(ts2, ts, atol=1e-6)
    np.testing.assert_allclose(poses2, poses, atol=1e-7)
    evo_t = file_interface.read_tum_trajectory_file(str(path))
    np.testing.assert_allclose(np.stack(evo_t.poses_se3), poses, atol=1e-7)
    # and we read evo's output
    file_interface.write_tum_trajectory_file(str(tmp_path / "evo.txt"), evo_t)
    _, poses3 = read_tum_trajectory(tmp_path / "evo.txt")
    np.testing.assert_allclose(poses3, poses, atol=1e-6)


def test_associate_greedy_unique():
    a = [0.0, 0.033, 0.066, 0.5]
    b = [0.001, 0.030, 0.031, 0.07, 0.9]
    ia, ib = associate(a, b, max_dt=0.02)
    assert ia.tolist() == [0, 1, 2] and ib.tolist() == [0, 2, 3]


def test_bad_trajectory_files(tmp_path):
    with pytest.raises(SlamInputError, match="missing.txt: file not found"):
        read_tum_trajectory(tmp_path / "missing.txt")
    p = tmp_path / "empty.txt"
    p.write_text("# nothing\n")
    with pytest.raises(SlamInputError, match="empty.txt: no poses"):
        read_tum_trajectory(p)
    p.write_text("0 1 2 3 0 0 0 1\n1 nan 2 3 0 0 0 1\n")
    with pytest.raises(SlamInputError, match="pose 1 .* NaN"):
        read_tum_trajectory(p)
    p.write_text("0 1 2 3 0 0 0\n")
    with pytest.raises(SlamInputError, match=":1: expected 8 columns"):
        read_tum_trajectory(p)
    p.write_text("0 1 2 3 0 0 0 2\n")
    with pytest.raises(SlamInputError, match="quaternion norm"):
        read_tum_trajectory(p)
    bad = np.tile(np.eye(4), (2, 1, 1))
    bad[1, 0, 0] = 2.0
    with pytest.raises(SlamInputError, match="pose 1 is not a rigid"):
        write_tum_trajectory(tmp_path / "w.txt", [0, 1], bad)
    q = tmp_path / "far.txt"
    write_tum_trajectory(q, [1000.0, 1001.0, 1002.0], _random_traj(3))
    write_tum_trajectory(p, [0.0, 1.0, 2.0], _random_traj(3))
    with pytest.raises(SlamInputError, match="no timestamp matches"):
        ate_from_files(q, p)
