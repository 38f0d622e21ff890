"""Camera pose parameterisation: 7 numbers ``[qw, qx, qy, qz, tx, ty, tz]`` for camera-to-world.

ESLAM optimises a quaternion (real part first, pytorch3d convention) and a translation as plain Euclidean
parameters. The quaternion is never renormalised; :func:`quaternion_to_matrix` divides by ``|q|^2`` so its scale
is harmless. :func:`matrix_to_quaternion` standardises the sign (``w >= 0``) so that the constant-velocity
extrapolation ``2 p_{t-1} - p_{t-2}`` never mixes the two antipodal representatives of one rotation.

All functions are pure PyTorch, keep leading batch dims ``[...]`` and are differentiable where stated.
"""

from __future__ import annotations

import math

import torch


def _quat_coefficients() -> torch.Tensor:
    """``[9, 16]``: row ``3 i + j`` holds the coefficients of ``R[i, j] - delta_ij`` in the products ``q_a q_b``
    (flattened ``a * 4 + b``, ``(w, x, y, z) = 0..3``), before the factor ``2 / |q|^2``."""
    w, x, y, z = range(4)
    rows = [
        {(y, y): -1, (z, z): -1}, {(x, y): 1, (z, w): -1}, {(x, z): 1, (y, w): 1},
        {(x, y): 1, (z, w): 1}, {(x, x): -1, (z, z): -1}, {(y, z): 1, (x, w): -1},
        {(x, z): 1, (y, w): -1}, {(y, z): 1, (x, w): 1}, {(x, x): -1, (y, y): -1},
    ]
    C = torch.zeros(9, 16, dtype=torch.float64)
    for r, terms in enumerate(rows):
        for (a, b), c in terms.items():
            C[r, 4 * a + b] = c
    return C


_QUAT_C = _quat_coefficients()


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of a (not necessarily unit) quaternion.

    ``R = I + 2 / |q|^2 * (a fixed linear map of the products q_a q_b)``, as one outer product and one matrix
    product: the tracker evaluates this every iteration, and a dozen scalar expressions cost a hundred autograd
    nodes (forward and backward) where this costs eight.

    Args:
        q: ``[..., 4]`` as ``(w, x, y, z)``; any non-zero scale.

    Returns:
        ``[..., 3, 3]`` rotation matrix (differentiable w.r.t. ``q``).
    """
    qq = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    two_s = 2.0 / (q * q).sum(-1)
    m = qq @ _QUAT_C.to(q).T  # [..., 9]
    eye = torch.eye(3, dtype=q.dtype, device=q.device).reshape(9)
    return (eye + two_s[..., None] * m).reshape(q.shape[:-1] + (3, 3))


def standardize_quaternion(q: torch.Tensor) -> torch.Tensor:
    """Flip the sign of quaternions with negative real part, so ``w >= 0``.

    Args:
        q: ``[..., 4]`` as ``(w, x, y, z)``.

    Returns:
        ``[..., 4]``, the same rotations with ``w >= 0``.
    """
    return torch.where(q[..., :1] < 0, -q, q)


def matrix_to_quaternion(R: torch.Tensor) -> torch.Tensor:
    """Unit quaternion ``(w, x, y, z)`` with ``w >= 0`` of a rotation matrix (not differentiable-safe at edges).

    Uses the numerically stable branch selection of pytorch3d (the best-conditioned of four candidates).

    Args:
        R: ``[..., 3, 3]`` rotation matrices.

    Returns:
        ``[..., 4]`` unit quaternions, real part first and non-negative.
    """
    m = R.reshape(R.shape[:-2] + (9,))
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = torch.unbind(m, -1)
    q_abs = torch.sqrt(
        torch.clamp(
            torch.stack(
                (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), -1
            ),
            min=0.0,
        )
    )
    cand = torch.stack(
        (
            torch.stack((q_abs[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01), -1),
            torch.stack((m21 - m12, q_abs[..., 1] ** 2, m10 + m01, m02 + m20), -1),
            torch.stack((m02 - m20, m10 + m01, q_abs[..., 2] ** 2, m12 + m21), -1),
            torch.stack((m10 - m01, m20 + m02, m21 + m12, q_abs[..., 3] ** 2), -1),
        ),
        -2,
    )
    cand = cand / (2.0 * q_abs[..., None].clamp(min=0.1))
    best = q_abs.argmax(-1)
    q = torch.gather(cand, -2, best[..., None, None].expand(best.shape + (1, 4))).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return standardize_quaternion(q)


def pose_to_matrix(p: torch.Tensor) -> torch.Tensor:
    """``[..., 7]`` ``(q, t)`` to ``[..., 4, 4]`` camera-to-world (differentiable)."""
    R = quaternion_to_matrix(p[..., :4])
    t = p[..., 4:7]
    top = torch.cat((R, t[..., None]), -1)
    bottom = torch.zeros(p.shape[:-1] + (1, 4), dtype=p.dtype, device=p.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat((top, bottom), -2)


def matrix_to_pose(T: torch.Tensor) -> torch.Tensor:
    """``[..., 4, 4]`` (or ``[..., 3, 4]``) camera-to-world to ``[..., 7]`` ``(q, t)`` with ``w >= 0``."""
    return torch.cat((matrix_to_quaternion(T[..., :3, :3]), T[..., :3, 3]), -1)


def align_sign(p: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Flip ``p``'s quaternion when it points away from ``reference``'s (``<q, q_ref> < 0``)."""
    dot = (p[..., :4] * reference[..., :4]).sum(-1, keepdim=True)
    q = torch.where(dot < 0, -p[..., :4], p[..., :4])
    return torch.cat((q, p[..., 4:]), -1)


def constant_velocity(p_prev: torch.Tensor, p_prev2: torch.Tensor) -> torch.Tensor:
    """ESLAM's constant-speed start: ``2 p_{t-1} - p_{t-2}`` componentwise on ``[q, t]``.

    The older quaternion is first put on the same hemisphere as the newer one (the sign fix ESLAM lacks), so
    a ``q`` / ``-q`` flip between frames cannot turn the extrapolation into nonsense.

    Args:
        p_prev: ``[..., 7]`` pose at ``t - 1``.
        p_prev2: ``[..., 7]`` pose at ``t - 2``.

    Returns:
        ``[..., 7]`` extrapolated pose with ``w >= 0``.
    """
    p2 = align_sign(p_prev2, p_prev)
    return normalize_pose(2 * p_prev - p2)


def normalize_pose(p: torch.Tensor) -> torch.Tensor:
    """``[..., 7]`` ``(q, t)`` with the quaternion scaled to unit length and ``w >= 0`` (the form a pose is stored
    in after an optimiser moved it off the unit sphere)."""
    q = p[..., :4] / p[..., :4].norm(dim=-1, keepdim=True).clamp(min=1e-12)
    return torch.cat((standardize_quaternion(q), p[..., 4:]), -1)


def rotation_angle(R: torch.Tensor) -> torch.Tensor:
    """Angle in radians (a 0-d tensor of ``R``'s dtype) of a ``[3, 3]`` rotation matrix, e.g. the relative rotation
    ``R_a^T R_b`` between two cameras; rounding beyond [-1, 1] in the trace is clamped."""
    return torch.arccos(((R.trace() - 1) / 2).clamp(-1.0, 1.0))


def pose_gap(a, b) -> tuple[float, float]:
    """Translation (metres) and rotation (degrees) between two ``[4, 4]`` camera-to-world transforms (tensors or
    arrays): the distance between their centres and the angle of ``R_a^T R_b``; the translation is the norm of
    ``a^-1 b``'s, as a pose graph measures it."""
    a, b = torch.as_tensor(a, dtype=torch.float64), torch.as_tensor(b, dtype=torch.float64)
    angle = math.degrees(float(rotation_angle(a[:3, :3].T @ b[:3, :3])))
    return float((a[:3, 3] - b[:3, 3]).norm()), angle


#: metres one radian of rotation counts as in :func:`pose_distance`
METRES_PER_RADIAN = 0.5


def pose_distance(a: torch.Tensor, b: torch.Tensor) -> float:
    """How far apart two cameras are, by their ``[4, 4]`` camera-to-world matrices: the distance between their
    centres in metres plus :data:`METRES_PER_RADIAN` per radian of the rotation between them (how redundant a
    keyframe is, how near a keyframe is to relocalise against)."""
    angle = float(rotation_angle(a[:3, :3].T @ b[:3, :3]))
    return float((a[:3, 3] - b[:3, 3]).norm()) + METRES_PER_RADIAN * angle


def rotation_vector(R: torch.Tensor) -> torch.Tensor:
    """``[3, 3]`` rotation -> ``[3]`` rotation vector (axis times angle, radians), for angles well below 180 degrees
    (the inverse of :func:`exp_se3`'s rotation there)."""
    angle = rotation_angle(R)
    axis = torch.stack((R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]))
    return axis / 2 if float(torch.sin(angle)) < 1e-9 else axis * (angle / (2 * torch.sin(angle)))


def skew(v: torch.Tensor) -> torch.Tensor:
    """``[3]`` -> ``[3, 3]`` cross-product matrix: ``skew(v) @ u == v x u`` (differentiable in ``v``)."""
    K = torch.zeros(3, 3, dtype=v.dtype, device=v.device)
    K[0, 1], K[0, 2], K[1, 0], K[1, 2], K[2, 0], K[2, 1] = -v[2], v[1], v[2], -v[0], -v[1], v[0]
    return K


def exp_se3(xi: torch.Tensor) -> torch.Tensor:
    """``[6]`` twist ``(rotation vector, translation)`` (radians, metres) -> ``[4, 4]`` rigid motion, exact in the
    rotation and first-order in the translation; a pose update left-multiplies it: ``T <- exp_se3(xi) @ T``."""
    w, t = xi[:3], xi[3:]
    theta = w.norm()
    K = skew(w)
    if float(theta) < 1e-12:
        R = torch.eye(3, dtype=xi.dtype, device=xi.device) + K
    else:
        R = (torch.eye(3, dtype=xi.dtype, device=xi.device) + torch.sin(theta) / theta * K
             + (1 - torch.cos(theta)) / theta**2 * (K @ K))
    T = torch.eye(4, dtype=xi.dtype, device=xi.device)
    T[:3, :3] = R
    T[:3, 3] = t
    return T
