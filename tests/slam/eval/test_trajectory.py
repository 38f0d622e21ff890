"""slam/eval/trajectory.py: how far apart consecutive poses are (frame_steps)."""

import math

import numpy as np
import pytest

from slam.eval import frame_steps


def _step(deg: float, cm: float) -> np.ndarray:
    a = math.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    T[0, 3] = cm / 100
    return T


def test_turns_and_moves_between_consecutive_poses():
    """Nine steps of 2 degrees and 3 cm, one of 10 degrees and 3 cm, from a pose that is not the identity (each
    step is measured in the frame of the pose before it)."""
    poses = [np.array(_step(30.0, 50.0))]
    for deg in [2.0] * 5 + [10.0] + [2.0] * 4:
        poses.append(poses[-1] @ _step(deg, 3.0))
    s = frame_steps(np.stack(poses))
    assert s["turn_deg"]["median"] == pytest.approx(2.0, abs=1e-6)
    assert s["turn_deg"]["max"] == pytest.approx(10.0, abs=1e-6)
    assert 2.0 < s["turn_deg"]["p95"] < 10.0
    assert s["move_cm"] == {"median": pytest.approx(3.0), "p95": pytest.approx(3.0), "max": pytest.approx(3.0)}


def test_too_few_poses_a_non_finite_pose_and_a_wrong_shape():
    assert frame_steps(np.eye(4)[None]) is None
    poses = np.stack([np.eye(4), _step(4.0, 1.0), np.full((4, 4), np.nan)])
    assert frame_steps(poses)["turn_deg"]["max"] == pytest.approx(4.0)  # the NaN pose is left out
    # the poses either side of a non-finite one are not one step apart: the 20 degrees across it are no step
    across = np.stack([np.eye(4), _step(4.0, 1.0), np.full((4, 4), np.nan), _step(24.0, 1.0), _step(30.0, 1.0)])
    s = frame_steps(across)
    assert s["turn_deg"]["max"] == pytest.approx(6.0) and s["turn_deg"]["median"] == pytest.approx(5.0)
    assert frame_steps(np.stack([np.eye(4), np.full((4, 4), np.nan), np.eye(4)])) is None
    with pytest.raises(ValueError, match=r"\[N, 4, 4\]"):
        frame_steps(np.zeros((3, 3, 4)))
