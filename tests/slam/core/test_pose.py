import math

import torch

from slam.core.pose import (align_sign, constant_velocity, matrix_to_pose, matrix_to_quaternion, normalize_pose,
                            pose_distance, pose_gap, pose_to_matrix, quaternion_to_matrix, rotation_angle,
                            skew, standardize_quaternion)


def _rand_quats(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return q / q.norm(dim=-1, keepdim=True)


def test_quaternion_matrix_roundtrip_and_sign():
    q = _rand_quats(200)
    R = quaternion_to_matrix(q)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=q.dtype).expand(200, 3, 3), atol=1e-10)
    assert torch.allclose(torch.linalg.det(R), torch.ones(200, dtype=q.dtype), atol=1e-10)
    q2 = matrix_to_quaternion(R)
    assert (q2[:, 0] >= 0).all()
    assert torch.allclose(q2, standardize_quaternion(q), atol=1e-8)
    # q and -q give the same matrix; the scale of q is harmless
    assert torch.allclose(quaternion_to_matrix(-3.0 * q), R, atol=1e-10)


def test_known_rotation():
    a = math.pi / 2
    q = torch.tensor([math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)], dtype=torch.float64)  # 90 deg about z
    R = quaternion_to_matrix(q)
    assert torch.allclose(R @ torch.tensor([1.0, 0, 0], dtype=torch.float64), torch.tensor([0.0, 1, 0], dtype=torch.float64), atol=1e-12)


def test_pose_matrix_roundtrip():
    q = _rand_quats(10, 1)
    t = torch.randn(10, 3, dtype=torch.float64)
    p = torch.cat((standardize_quaternion(q), t), -1)
    T = pose_to_matrix(p)
    assert T.shape == (10, 4, 4)
    assert torch.allclose(T[:, 3], torch.tensor([0, 0, 0, 1.0], dtype=torch.float64).expand(10, 4))
    assert torch.allclose(matrix_to_pose(T), p, atol=1e-8)


def test_constant_velocity_linear_and_sign_flip():
    p0 = torch.tensor([1.0, 0, 0, 0, 0, 0, 0], dtype=torch.float64)
    a = 0.1
    p1 = torch.tensor([math.cos(a / 2), 0, 0, math.sin(a / 2), 0.1, 0.2, 0.0], dtype=torch.float64)
    out = constant_velocity(p1, p0)
    assert torch.allclose(out[4:], torch.tensor([0.2, 0.4, 0.0], dtype=torch.float64))
    # rotation extrapolates to about 2a about z
    R = quaternion_to_matrix(out[:4])
    angle = math.atan2(R[1, 0].item(), R[0, 0].item())
    assert abs(angle - 2 * a) < 1e-3
    # the same rotations with the older quaternion negated give the same answer (sign handling)
    p0_neg = p0.clone()
    p0_neg[:4] = -p0_neg[:4]
    assert torch.allclose(constant_velocity(p1, p0_neg), out, atol=1e-12)
    assert out[0] >= 0


def test_align_sign():
    p = torch.tensor([-1.0, 0, 0, 0, 1, 2, 3])
    r = torch.tensor([1.0, 0, 0, 0, 0, 0, 0])
    assert torch.equal(align_sign(p, r), torch.tensor([1.0, 0, 0, 0, 1, 2, 3]))


def test_pose_gradients_flow():
    p = torch.tensor([0.9, 0.1, 0.2, 0.3, 1.0, 2.0, 3.0], requires_grad=True)
    pose_to_matrix(p).sum().backward()
    assert p.grad is not None and torch.isfinite(p.grad).all()


def test_normalize_pose_unit_quaternion_with_w_nonnegative_and_translation_kept():
    p = torch.tensor([[-2.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0], [0.0, 0.0, 3.0, 4.0, -1.0, 0.0, 0.5]])
    n = normalize_pose(p)
    assert torch.allclose(n[:, :4].norm(dim=-1), torch.ones(2))
    assert torch.equal(n[0, :4], torch.tensor([1.0, 0.0, 0.0, 0.0]))  # -q is the same rotation: w >= 0
    assert torch.allclose(n[1, :4], torch.tensor([0.0, 0.0, 0.6, 0.8]))
    assert torch.equal(n[:, 4:], p[:, 4:])
    assert torch.allclose(pose_to_matrix(n), pose_to_matrix(p))  # the same camera


def test_rotation_angle_of_known_rotations():
    for deg in (0.0, 1.0, 37.0, 90.0, 179.0):
        a = math.radians(deg)
        R = torch.tensor([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]],
                         dtype=torch.float64)
        assert math.isclose(float(rotation_angle(R)), a, abs_tol=1e-6)
    # rounding that pushes the trace past 3 is clamped, not NaN
    assert float(rotation_angle(torch.eye(3) * (1 + 1e-7))) == 0.0


def test_pose_distance_counts_half_a_metre_per_radian():
    a = math.radians(30.0)
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = torch.tensor([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]],
                             dtype=torch.float64)
    T[:3, 3] = torch.tensor([0.3, 0.0, 0.4], dtype=torch.float64)
    assert math.isclose(pose_distance(torch.eye(4, dtype=torch.float64), T), 0.5 + 0.5 * a, rel_tol=1e-12)
    assert math.isclose(pose_distance(T, T), 0.0, abs_tol=1e-6)


def test_pose_gap_is_the_relative_transform_of_a_to_b_for_tensors_and_arrays():
    a = math.radians(30.0)
    A = torch.eye(4, dtype=torch.float64)
    A[:3, :3] = torch.tensor([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]],
                             dtype=torch.float64)
    A[:3, 3] = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    rel = torch.eye(4, dtype=torch.float64)
    rel[:3, :3] = A[:3, :3].T  # a -30 degree turn about z
    rel[:3, 3] = torch.tensor([0.3, 0.0, 0.4], dtype=torch.float64)
    B = A @ rel
    dt, dr = pose_gap(A, B)
    assert math.isclose(dt, 0.5, rel_tol=1e-12) and math.isclose(dr, 30.0, rel_tol=1e-9)
    assert pose_gap(A.numpy(), B.numpy()) == (dt, dr)


def test_skew_is_the_cross_product_and_carries_gradients():
    v = torch.tensor([0.3, -1.2, 2.5], dtype=torch.float64, requires_grad=True)
    u = torch.tensor([-0.7, 0.4, 1.1], dtype=torch.float64)
    out = skew(v) @ u
    assert torch.allclose(out, torch.linalg.cross(v, u))
    out.sum().backward()
    assert torch.allclose(v.grad, torch.linalg.cross(u, torch.ones(3, dtype=torch.float64)))
