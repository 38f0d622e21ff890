"""Depth ICP between consecutive frames recovers their relative pose (the tracker's start with tracking.init=icp)."""

import math

import pytest
import torch

from slam.data import load_dataset
from slam.core.odometry import hold_unobserved, icp_relative_pose, pyramid, unobserved_directions
from slam.data import Intrinsics


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


def _wall_depth(cam_to_wall: torch.Tensor, intr, generator) -> torch.Tensor:
    """``[H, W]`` depth (metres, Kinect-like noise) of the plane z = 0.6 m seen from ``cam_to_wall`` ``[4, 4]``."""
    v, u = torch.meshgrid(torch.arange(intr.height, dtype=torch.float64), torch.arange(intr.width, dtype=torch.float64),
                          indexing="ij")
    rays = torch.stack(((u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, torch.ones_like(u)), -1)
    rays = rays @ cam_to_wall[:3, :3].T
    z = (0.6 - cam_to_wall[2, 3]) / rays[..., 2]  # the ray's depth along the optical axis (its z in the camera is 1)
    return (z + torch.randn(z.shape, generator=generator, dtype=z.dtype) * (0.0012 + 0.0019 * (z - 0.4) ** 2)).float()


def _motion(roll_deg: float, tilt_deg: float, t) -> torch.Tensor:
    """Turn ``roll_deg`` about the optical axis (the wall's normal) after tilting ``tilt_deg`` about x, then move."""
    a, b = math.radians(roll_deg), math.radians(tilt_deg)
    rz = torch.tensor([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]], dtype=torch.float64)
    rx = torch.tensor([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]], dtype=torch.float64)
    m = torch.eye(4, dtype=torch.float64)
    m[:3, :3], m[:3, 3] = rz @ rx, torch.tensor(t, dtype=torch.float64)
    return m


def test_facing_a_wall_icp_fixes_what_depth_sees_and_the_hold_puts_back_the_previous_pose_where_it_is_blind():
    # a camera 0.6 m from a flat wall, as at the walk's end wall (docs/robustness.md, "Depth ICP holds what it
    # cannot see"): depth fixes the distance and the two tilts, not the turn about the normal or a slide along it,
    # where ICP's result is whatever the noise makes of its start (here 2.6 cm and 1.0 degrees from a start 3.4 cm
    # and 2.3 degrees off, the truth 0.4 cm and 0.3 degrees)
    intr = Intrinsics(130.0, 130.0, 79.5, 59.5, 120, 160)
    g = torch.Generator().manual_seed(0)
    true = _motion(0.3, 1.0, [0.004, 0.002, 0.01])  # slight roll and slide, 1 degree tilt, 1 cm closer
    prev, cur = _wall_depth(torch.eye(4, dtype=torch.float64), intr, g), _wall_depth(true, intr, g)
    guess = _motion(2.3, 0.0, [0.034, 0.002, 0.0])  # a prediction 2 degrees and 3 cm off where depth is blind
    res = icp_relative_pose(prev, cur, intr, init=guess)
    assert res.ok
    rel = res.relative.double()
    assert abs(float(rel[2, 3] - true[2, 3])) < 1e-3 and abs(float(rel[1, 2] - true[1, 2])) < 2e-3  # seen: fixed
    assert abs(float(rel[0, 3] - true[0, 3])) > 1.5e-2  # blind: the slide is not measured
    blind = unobserved_directions(prev, intr, 3e-4)
    assert blind.shape[1] == 3  # measured eigenvalue ratios: 1e-5 to 2e-4 for the three, 2e-2 and up
    held = hold_unobserved(rel, torch.eye(4, dtype=torch.float64), blind)  # the previous pose there
    assert abs(float(held[0, 3])) < 2e-3 and abs(math.degrees(math.atan2(float(held[1, 0]), float(held[0, 0])))) < 0.2
    assert abs(float(held[2, 3] - true[2, 3])) < 1e-3 and abs(float(held[1, 2] - true[1, 2])) < 2e-3  # seen: kept


def test_a_room_or_a_real_office_has_no_unobserved_direction(tiny_seq, shared_data):
    ds = load_dataset(tiny_seq)
    for k in (0, 12, 23):
        assert unobserved_directions(torch.as_tensor(ds[k].depth), ds.intrinsics, 3e-4).shape[1] == 0
    real = load_dataset(shared_data / "tum_fr1_rpy_0_124")
    for k in (0, 40, 80, 120):  # TUM fr1_rpy: a desk, a monitor, the walls; the weakest ratio measured was 3e-3
        assert unobserved_directions(torch.as_tensor(real[k].depth), real.intrinsics, 3e-4).shape[1] == 0


def test_the_icp_kernels_give_the_references_registration(shared_data):
    # the numba registration (slam.core.odometry_kernels) stands for the tensor-op reference: the same matches, and
    # the normal equations summed in another order, so the pose agrees to the last bits of a double and the float32
    # pose handed on is the reference's; checked on real frames, from the loop's start and from 2 degrees and 3 cm off
    from slam.core import odometry
    from slam.core.odometry_kernels import associate, level_points

    real = load_dataset(shared_data / "tum_fr1_rpy_0_124")
    off = _motion(2.0, 0.0, [0.03, 0.0, 0.0]).float()
    for i, j, init in ((0, 1, None), (40, 42, None), (80, 81, off)):
        a, b = torch.as_tensor(real[i].depth), torch.as_tensor(real[j].depth)
        fast = icp_relative_pose(a, b, real.intrinsics, init=init)
        ref = icp_relative_pose(a, b, real.intrinsics, init=init, kernel=False)
        assert fast.ok and ref.ok and torch.equal(fast.relative, ref.relative)
        assert abs(fast.inliers - ref.inliers) < 1e-12 and abs(fast.rmse_m - ref.rmse_m) < 1e-12
    # too few matches from a start far off: both stop at the same step and report the same failure
    far = _motion(0.0, 0.0, [0.0, 0.0, 3.0]).float()
    fast = icp_relative_pose(a, b, real.intrinsics, init=far)
    ref = icp_relative_pose(a, b, real.intrinsics, init=far, kernel=False)
    assert not fast.ok and not ref.ok and torch.equal(fast.relative, ref.relative)
    assert abs(fast.inliers - ref.inliers) < 1e-12 and fast.rmse_m == ref.rmse_m == float("inf")
    # depths of two sizes are refused by name, either way
    for kernel in (True, False):
        with pytest.raises(ValueError, match=r"one size, got \(\d+, \d+\) and \(\d+, \d+\)"):
            icp_relative_pose(a, b[:-2], real.intrinsics, kernel=kernel)
    # a level's points, normals and their validity, NaN depth included
    depth = torch.as_tensor(real[10].depth).double()
    depth[40, 50] = float("nan")
    cam = (real.intrinsics.fx, real.intrinsics.fy, real.intrinsics.cx, real.intrinsics.cy)
    vp, np_, okp = odometry._level_points(depth, cam, 0.1)
    v, n, ok = torch.empty_like(vp), torch.empty_like(np_), torch.empty_like(okp)
    level_points(depth.numpy(), *cam, 0.1, v.numpy(), n.numpy(), ok.numpy())
    assert torch.equal(ok, okp) and int(ok.sum()) > depth.numel() // 3
    assert not any(bool(ok[r, c]) for r, c in ((40, 50), (39, 50), (41, 50), (40, 49), (40, 51)))  # NaN and beside
    assert torch.allclose(v[~v.isnan()], vp[~vp.isnan()], rtol=0, atol=0)
    assert float((n - np_)[ok].abs().max()) < 1e-12
    # points the projection must drop, as the reference does: NaN, behind the camera, outside the image
    depth = torch.as_tensor(real[10].depth).double()
    cam = (real.intrinsics.fx, real.intrinsics.fy, real.intrinsics.cx, real.intrinsics.cy)
    vp, np_, okp = odometry._level_points(depth, cam, 0.1)
    pts, pnrm = vp[okp].clone(), np_[okp].clone()
    pts[::97] = float("nan")
    pts[5::89, 2] = -pts[5::89, 2]
    pts[7::83, 0] += 50.0
    T = odometry.exp_se3(torch.tensor([0.01, -0.02, 0.005, 0.01, 0.0, -0.02], dtype=torch.float64))
    want = odometry._associate(pts, pnrm, T, (vp, np_, okp), cam, 0.1, 0.3, 0.8)
    q, qn = pts @ T[:3, :3].T + T[:3, 3], pnrm @ T[:3, :3].T  # moved as the reference moves them
    P = q.shape[0]
    idx, src, tgt, nrm = torch.empty(P, dtype=torch.int64), *(torch.empty(P, 3, dtype=q.dtype) for _ in range(3))
    m = associate(q.numpy(), qn.contiguous().numpy(), vp.numpy(), np_.numpy(), okp.numpy(), *cam, 0.1, 0.3, 0.8,
                  idx.numpy(), src.numpy(), tgt.numpy(), nrm.numpy())
    got = idx[:m], tgt[:m], nrm[:m], src[:m]
    assert 0 < m < P - 3 * (P // 100)
    assert all(torch.equal(g, w) for g, w in zip(got, want))


def test_in_a_corridor_with_kinect_like_depth_smoothed_normals_measure_the_forward_motion():
    # the synthetic walk of data seed 1 down a corridor (frames 210-230): walls, floor and ceiling run along the
    # motion, the far end is past the 4.5 m range, and the noise of the far depth (2.6 cm at 4 m) tilts raw
    # central-difference normals at random; such points hold the camera where it was along the optical axis, so ICP
    # from the true motion gave back about 0.7 of each 1.9 cm step (docs/robustness.md, "Depth ICP's normals")
    from slam.data.synthetic.config import walk_config
    from slam.data.synthetic.sequence import scene_and_path, sensor_frame

    cfg = walk_config(seed=1)
    scene, poses = scene_and_path(cfg)
    intr = cfg.intrinsics()

    def depth(i):
        return torch.as_tensor(sensor_frame(scene, poses[i], cfg, i)[1], dtype=torch.float32)

    errors = {1: [], 3: []}
    for i in range(212, 232, 3):
        prev, cur = depth(i - 1), depth(i)
        true = torch.linalg.solve(torch.as_tensor(poses[i - 1]), torch.as_tensor(poses[i])).double()
        for smooth in errors:
            rel = icp_relative_pose(prev, cur, intr, init=true.float(), smooth=smooth).relative.double()
            errors[smooth].append(float(torch.linalg.solve(true, rel)[2, 3]))
    assert abs(sum(errors[3]) / len(errors[3])) < 2.5e-3  # measured: -1.1 mm a frame
    assert sum(errors[1]) / len(errors[1]) < -5e-3  # raw normals: -14 mm a frame
    with pytest.raises(ValueError, match="odd"):
        icp_relative_pose(prev, cur, intr, smooth=4)


def test_with_depth_noise_growing_with_distance_the_plane_gate_halves_icps_error(monkeypatch):
    # the synthetic walk's first 130 frames (Kinect-like depth: noise 0.0012 + 0.0019 (z - 0.4)^2 m, nothing past
    # 4.5 m), ICP from the true motion of each pair: gating the matches' point distance at max_dist dropped far
    # points whose residual to the plane was small, and left the pose 1.8 mm off on average; gating the distance to
    # the target's plane there (the points' at 3x) 0.8 mm (docs/robustness.md, "Depth ICP's gate")
    from slam.core import odometry
    from slam.data.synthetic.config import walk_config
    from slam.data.synthetic.sequence import scene_and_path, sensor_frame

    cfg = walk_config(frames=130)
    scene, poses = scene_and_path(cfg)
    intr = cfg.intrinsics()
    depths = [torch.as_tensor(sensor_frame(scene, poses[i], cfg, i)[1], dtype=torch.float32) for i in range(1, 130)]

    def mean_error(gate: float) -> float:
        monkeypatch.setattr(odometry, "POINT_GATE", gate)
        errors = []
        for i in range(2, 130):
            true = torch.linalg.solve(torch.as_tensor(poses[i - 1]), torch.as_tensor(poses[i])).double()
            rel = icp_relative_pose(depths[i - 2], depths[i - 1], intr, init=true.float()).relative.double()
            errors.append(float((rel[:3, 3] - true[:3, 3]).norm()))
        return sum(errors) / len(errors)

    assert odometry.POINT_GATE == 3.0
    plane, point = mean_error(3.0), mean_error(1.0)
    assert plane < 1.2e-3 and plane < 0.6 * point, (plane, point)
