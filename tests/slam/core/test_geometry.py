import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slam.errors import SlamInputError
from slam.core.geometry import check_rigid, poses_from_tum, poses_to_tum


def _poses(n=5, seed=0):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(n, 3))
    return poses


def test_tum_rows_round_trip_and_keep_qw_non_negative():
    poses = _poses()
    rows = poses_to_tum(poses)
    assert rows.shape == (5, 7) and (rows[:, 6] >= 0).all()
    np.testing.assert_allclose(poses_from_tum(rows), poses, atol=1e-12)
    # TUM files round quaternions to 4 decimals: the rows are renormalised, so the result is still rigid
    check_rigid(poses_from_tum(np.round(rows, 4)), "rounded", tol=1e-9)


def test_check_rigid_masks_lost_poses_and_names_the_bad_one():
    poses = _poses()
    poses[2] = np.nan
    assert check_rigid(poses, "seq", allow_nan=True).tolist() == [True, True, False, True, True]
    with pytest.raises(SlamInputError, match="seq: pose 2 contains NaN"):
        check_rigid(poses, "seq")
    poses[2] = np.eye(4)
    poses[3, :3, :3] *= 1.01  # a scaled rotation
    with pytest.raises(SlamInputError, match="seq: pose 3 is not a rigid transform"):
        check_rigid(poses, "seq")
    poses[3] = np.eye(4)
    poses[4, 3] = [0.0, 0.0, 0.1, 1.0]  # last row not 0 0 0 1
    with pytest.raises(SlamInputError, match="pose 4 is not a rigid"):
        check_rigid(poses, "seq")


def test_eval_re_exports_the_same_functions():
    from slam.eval import trajectory

    assert (trajectory.check_rigid, trajectory.poses_from_tum, trajectory.poses_to_tum) == (
        check_rigid, poses_from_tum, poses_to_tum)
