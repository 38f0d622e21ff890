"""The Gauss-Newton tracker's prior towards its start pose (``tracking.gn_prior``, ``tracking.gn_prior_shape``;
slam/engine/gauss_newton.py): its metric in the solver's tangent, set on the camera's own axes."""

from __future__ import annotations

import torch

from slam.core.odometry import normal_matrix
from slam.core.pose import skew


def prior_metric(H: torch.Tensor, kappa: float, T: torch.Tensor, shape: str = "camera", depth=None,
                 intrinsics=None) -> torch.Tensor:
    """``[6, 6]`` metric of the prior towards the start (``tracking.gn_prior`` = kappa) in the solver's tangent at
    camera-to-world ``T`` (``tracking.gn_prior_shape``):

    * ``camera``: kappa times the mean curvature of ``H`` about the camera's rotation axes and along its
      translation axes, the same on every axis of each, set in the camera's frame and moved to the solver's: a
      direction the draw barely constrains is held as firmly as a well-constrained one, wherever the world's
      origin is;
    * ``world``: the same in the solver's tangent itself (rotations about the world's origin, so a camera far from
      it has its rotations held by their lever arm);
    * ``geometry``: the depth image's normal matrix (:func:`slam.core.odometry.normal_matrix`), scaled in the
      camera's frame so that each group's mean diagonal is ``camera``'s: held as firmly as the depth holds each
      direction.
    """
    if kappa == 0:
        return torch.zeros_like(H)
    if shape == "world":
        return kappa * torch.diag(_group_means(torch.diag(H)))
    M = camera_adjoint(T).to(H)
    Minv = torch.linalg.inv(M)
    mean = _group_means(torch.diag(Minv @ H @ Minv.T))  # H about the camera's own axes
    N = normal_matrix(depth, intrinsics) if shape == "geometry" else None
    if N is None:
        return kappa * M @ torch.diag(mean) @ M.T
    scale = torch.sqrt(mean / _group_means(torch.diag(N).to(H)).clamp(min=1e-30))
    return kappa * M @ (scale[:, None] * N.to(H) * scale[None, :]) @ M.T


def _group_means(d: torch.Tensor) -> torch.Tensor:
    """``[6]`` diagonal (rotation, translation) -> ``[6]``: each group's mean on each of its axes."""
    return torch.cat((d[:3].mean().expand(3), d[3:].mean().expand(3)))


def camera_adjoint(T: torch.Tensor) -> torch.Tensor:
    """``[6, 6]`` float64 map of a camera-frame twist (rotation, translation) to the solver's tangent (left twists
    about the world origin, as ``exp_se3(step) @ T``) at camera-to-world ``T`` ``[4, 4]``; a normal-equations row
    ``[p x n, n]`` of a camera-frame point and normal moves as ``[R (p x n) + t x R n, R n]``."""
    Td = T.detach().to("cpu", torch.float64)
    R, t = Td[:3, :3], Td[:3, 3]
    M = torch.zeros(6, 6, dtype=torch.float64)
    M[:3, :3], M[:3, 3:], M[3:, 3:] = R, skew(t) @ R, R
    return M
