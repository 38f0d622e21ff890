"""The pose graph and the correction of every frame: a drifted square closed by one loop, the correction put where
the tracker was not trusted, and frames moved with their keyframes."""

import numpy as np
import pytest

pytest.importorskip("gtsam")

from slam.loop.correct import correct_frames  # noqa: E402
from slam.loop.graph import Edge, odometry_sigmas, optimize  # noqa: E402


def _yaw(a, t):
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = t
    return T


def _square(n_side=5, step=0.5):
    """Poses around a square (heading along the path), returning to the start: ``[4 n_side + 1, 4, 4]``."""
    poses, T = [np.eye(4)], np.eye(4)
    for side in range(4):
        for i in range(n_side):
            T = T @ _yaw(np.pi / 2 if (i == n_side - 1) else 0.0, [step, 0, 0])
            poses.append(T.copy())
    return np.stack(poses)


def _odometry(truth, bias):
    est = [truth[0]]
    for a in range(len(truth) - 1):
        rel = np.linalg.inv(truth[a]) @ truth[a + 1]
        est.append(est[-1] @ rel @ bias)
    return np.stack(est)


def test_one_loop_closes_a_drifted_square():
    truth = _square()
    est = _odometry(truth, _yaw(0.01, [0.01, 0.0, 0.0]))
    edges = [Edge(a, a + 1, np.linalg.inv(est[a]) @ est[a + 1],
                  odometry_sigmas(np.linalg.inv(est[a]) @ est[a + 1], True)) for a in range(len(est) - 1)]
    end_before = np.linalg.norm(est[-1, :3, 3] - truth[-1, :3, 3])
    loop = Edge(0, len(est) - 1, np.linalg.inv(truth[0]) @ truth[-1], np.full(6, 0.01), robust=True)
    after = optimize(est, edges + [loop])
    err_before = np.linalg.norm(est[:, :3, 3] - truth[:, :3, 3], axis=1)
    err_after = np.linalg.norm(after[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert end_before > 0.3 and err_after[-1] < 0.05
    assert err_after.mean() < 0.5 * err_before.mean()
    np.testing.assert_allclose(after[0], est[0], atol=1e-6)  # the first pose is the anchor


def test_the_correction_goes_where_the_tracker_slipped():
    truth = _square()
    slip = 7
    est = _odometry(truth, np.eye(4))
    est[slip + 1:] = _yaw(0.0, [0.0, 0.4, 0.0]) @ est[slip + 1:]  # a 40 cm slip between two frames
    edges = []
    for a in range(len(est) - 1):
        rel = np.linalg.inv(est[a]) @ est[a + 1]
        edges.append(Edge(a, a + 1, rel, odometry_sigmas(rel, trusted=a != slip)))
    after = optimize(est, edges + [Edge(0, len(est) - 1, np.eye(4), np.full(6, 0.01), robust=True)])
    err = np.linalg.norm(after[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert err.max() < 0.03, err  # the whole slip was put on the untrusted edge


def test_frames_move_with_their_keyframes():
    truth = _square()
    keys = [0, 10, 20]
    after = truth[keys].copy()
    assert np.allclose(correct_frames(truth, keys, truth[keys], after), truth)
    after[1] = _yaw(0.0, [0.0, 0.2, 0.0]) @ after[1]
    after[2] = _yaw(0.0, [0.0, 0.2, 0.0]) @ after[2]
    out = correct_frames(truth, keys, truth[keys], after)
    moved = out[:, 1, 3] - truth[:, 1, 3]
    np.testing.assert_allclose(moved[[0, 5, 10, 20]], [0.0, 0.1, 0.2, 0.2], atol=1e-9)
    assert np.allclose(moved[20:], 0.2)  # held after the last keyframe
