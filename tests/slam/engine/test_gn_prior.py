"""The Gauss-Newton tracker's prior (slam/engine/gn_prior.py): set on the camera's own axes, so the same camera
and data give the same prior wherever the world's origin is."""

import math

import torch

from slam.core.pose import exp_se3
from slam.data import Intrinsics
from slam.engine.gn_prior import camera_adjoint, prior_metric

INTR = Intrinsics(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)
_v, _u = torch.meshgrid(torch.arange(60.0), torch.arange(80.0), indexing="ij")
#: a bumpy surface about 2 m ahead: its geometry holds every direction of motion
BUMPY = 2.0 + 0.3 * torch.sin(_u / 7) + 0.2 * torch.cos(_v / 5)


def test_the_prior_is_set_in_the_cameras_frame_wherever_the_world_origin_is():
    """``gn_prior_shape``: the twist map moves camera-frame normal-equation rows to the solver's tangent (the same
    points and normals in the world); ``camera`` and ``geometry`` give the same prior for the same camera and data
    seen from a world whose origin is 20 m away, where ``world`` does not; each group's mean diagonal in the
    camera's frame is kappa times the data's; facing a single wall ``geometry`` holds nothing along the wall."""
    T = exp_se3(torch.tensor([0.3, -0.2, 0.5, 1.0, 2.0, -0.5], dtype=torch.float64))
    g = torch.Generator().manual_seed(0)
    p = torch.randn(500, 3, dtype=torch.float64, generator=g)
    n = torch.nn.functional.normalize(torch.randn(500, 3, dtype=torch.float64, generator=g), dim=-1)
    J_c = torch.cat((torch.linalg.cross(p, n, dim=-1), n), -1)
    R, t = T[:3, :3], T[:3, 3]
    pw, nw = p @ R.T + t, n @ R.T
    J_w = torch.cat((torch.linalg.cross(pw, nw, dim=-1), nw), -1)
    M = camera_adjoint(T)
    assert torch.allclose(M @ (J_c.T @ J_c) @ M.T, J_w.T @ J_w, rtol=1e-9, atol=1e-9)

    H_c = J_c.T @ J_c  # the data's curvature in the camera's frame
    shift = torch.eye(4, dtype=torch.float64)
    shift[:3, 3] = torch.tensor([20.0, 0.0, 0.0], dtype=torch.float64)  # the same scene, the origin 20 m away
    priors = {}
    for name, pose in (("near", T), ("far", shift @ T)):
        Mp = camera_adjoint(pose)
        H = Mp @ H_c @ Mp.T
        Minv = torch.linalg.inv(Mp)
        for shape in ("camera", "world", "geometry"):
            P = prior_metric(H, 0.03, pose, shape, BUMPY, INTR)
            priors[name, shape] = Minv @ P @ Minv.T  # back in the camera's frame
    for shape in ("camera", "geometry"):
        assert torch.allclose(priors["near", shape], priors["far", shape], rtol=1e-6, atol=1e-9), shape
        d = torch.diag(priors["near", shape])
        assert torch.isclose(d[:3].mean(), 0.03 * torch.diag(H_c)[:3].mean())
        assert torch.isclose(d[3:].mean(), 0.03 * torch.diag(H_c)[3:].mean())
    assert not torch.allclose(priors["near", "world"], priors["far", "world"], rtol=1e-2)

    wall = torch.full((60, 80), 2.0)  # a flat wall 2 m ahead, the camera at the origin
    eye = torch.eye(4, dtype=torch.float64)
    H = torch.diag(torch.tensor([4.0, 5.0, 6.0, 100.0, 200.0, 300.0], dtype=torch.float64))
    P = prior_metric(H, 0.03, eye, "geometry", wall, INTR)
    slide = torch.tensor([0.0, 0.0, 0.0, 1.0, 0.0, 0.0], dtype=torch.float64)  # along the wall
    push = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 1.0], dtype=torch.float64)  # towards it
    assert float(slide @ P @ slide) < 1e-6 * float(push @ P @ push)
    iso = prior_metric(H, 0.03, eye, "camera")
    assert math.isclose(float(slide @ iso @ slide), float(push @ iso @ push)) and float(push @ iso @ push) > 0
