"""Depth ICP between consecutive frames recovers their relative pose (the tracker's start with tracking.init=icp)."""

import math

import torch

from slam.data import load_dataset
from slam.core.odometry import icp_relative_pose, pyramid


def _angle_deg(R):
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(R.trace()) - 1) / 2))))


def test_recovers_the_motion_between_two_synthetic_frames(tiny_seq):
    ds = load_dataset(tiny_seq)
    gt = ds.gt_poses.double()
    for i in (1, 5, 9):
        a, b = ds[i - 1], ds[i + 2]  # three frames apart: a larger motion than the loop ever asks for
        rel_gt = torch.linalg.solve(gt[i - 1], gt[i + 2])
        res = icp_relative_pose(torch.as_tensor(a.depth), torch.as_tensor(b.depth), ds.intrinsics)
        assert res.ok and res.inliers > 0.5
        rel = res.relative.double()
        assert float((rel[:3, 3] - rel_gt[:3, 3]).norm()) < 1e-3  # metres
        assert _angle_deg(rel[:3, :3].T @ rel_gt[:3, :3]) < 0.05


def test_reports_failure_instead_of_a_pose_when_there_is_no_depth(tiny_seq):
    ds = load_dataset(tiny_seq)
    d = torch.as_tensor(ds[0].depth)
    res = icp_relative_pose(d, torch.zeros_like(d), ds.intrinsics)
    assert not res.ok and torch.equal(res.relative, torch.eye(4))


def test_the_pyramid_keeps_enough_points_at_any_size():
    assert pyramid(60, 80) == (2, 1) and pyramid(184, 248) == (4, 2) and pyramid(480, 640) == (8, 4)
