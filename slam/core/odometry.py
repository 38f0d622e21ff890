"""Frame-to-frame depth odometry: projective point-to-plane ICP between two depth images.

The neural tracker refines a pose from a starting guess. ESLAM's, constant velocity, is far off whenever the camera
accelerates or turns quickly (the first frames of TUM fr1_rpy turn 4 degrees per frame from rest). Two consecutive
depth images pin down their relative motion independently of the map: :func:`icp_relative_pose` estimates it
(KinectFusion-style: projective association, point-to-plane residuals, Gauss-Newton on a twist, coarse to fine)
and reports ``ok=False`` when it does not converge or keeps too few matches, so the caller falls back.

Conventions: OpenCV camera (x right, y down, z forward), depth in metres (0 invalid), poses camera-to-world
``[4, 4]``. Nothing here is differentiable (torch.no_grad); float64 inside for the 6x6 solves.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from slam.core.camera import backproject
from slam.core.pose import exp_se3, rotation_vector


#: a match's points may lie this many times a level's ``max_dist`` apart (``max_dist`` bounds the distance to the
#: target's plane): far, noisy points lie a pixel's footprint from their match along the surface, and a gate at
#: ``max_dist`` dropped them, doubling ICP's error on Kinect-like depth (docs/robustness.md, "Depth ICP's gate")
POINT_GATE = 3.0


@dataclass
class ICPResult:
    """``relative``: ``[4, 4]`` pose of the current camera in the previous camera's frame (``T_prev^-1 T_cur``);
    ``inliers``: share of the current frame's valid points with a correspondence at the finest level;
    ``rmse_m``: point-to-plane RMS residual of those (metres); ``ok``: converged with enough inliers."""

    relative: torch.Tensor
    inliers: float
    rmse_m: float
    ok: bool


def pyramid(height: int, width: int, target: int = 8000) -> tuple[int, int]:
    """Downsampling factors ``(coarse, fine)`` for an image: the fine level is the largest power-of-two reduction
    that still keeps ``target`` pixels (full resolution below that), the coarse one twice as coarse. A fixed
    pyramid failed on small images: at 60x80 its 15x20 and 30x40 levels drifted by a centimetre per frame on the
    synthetic room, where full resolution registers to a tenth of a millimetre."""
    f = 1
    while (height // (2 * f)) * (width // (2 * f)) >= target:
        f *= 2
    return 2 * f, f


def _downsample(depth: torch.Tensor, factor: int) -> torch.Tensor:
    """Depth ``[H, W]`` -> ``[H // f, W // f]``: the top-left sample of each block (no averaging across edges)."""
    return depth[::factor, ::factor].contiguous()


def _vertices(depth: torch.Tensor, fx: float, fy: float, cx: float, cy: float) -> torch.Tensor:
    """Camera-frame points ``[H, W, 3]`` of a depth image (0 where depth is 0)."""
    H, W = depth.shape
    v, u = torch.meshgrid(torch.arange(H, dtype=depth.dtype, device=depth.device),
                          torch.arange(W, dtype=depth.dtype, device=depth.device), indexing="ij")
    return backproject(u, v, depth, fx, fy, cx, cy)


def _normals(vert: torch.Tensor, depth: torch.Tensor, max_jump: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit normals ``[H, W, 3]`` from central differences, and a validity mask ``[H, W]`` (depth on all four
    neighbours, no depth jump above ``max_jump`` relative)."""
    n = torch.zeros_like(vert)
    valid = torch.zeros(depth.shape, dtype=torch.bool, device=depth.device)
    dx = vert[1:-1, 2:] - vert[1:-1, :-2]
    dy = vert[2:, 1:-1] - vert[:-2, 1:-1]
    c = torch.linalg.cross(dx, dy, dim=-1)
    norm = c.norm(dim=-1, keepdim=True)
    d = depth[1:-1, 1:-1]
    neigh = torch.stack((depth[1:-1, 2:], depth[1:-1, :-2], depth[2:, 1:-1], depth[:-2, 1:-1]), -1)
    ok = (d > 0) & (neigh > 0).all(-1) & ((neigh - d[..., None]).abs() < max_jump * d[..., None]).all(-1)
    ok &= norm[..., 0] > 1e-12
    n[1:-1, 1:-1] = -c / norm.clamp(min=1e-12)  # facing the camera: dx x dy points away for y-down images
    valid[1:-1, 1:-1] = ok
    return n, valid


def smooth_normals(nrm: torch.Tensor, ok: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Normals ``[H, W, 3]`` averaged over the valid ones (``ok`` ``[H, W]``) of ``k`` pixels square and made unit
    again, and their validity: valid before, with more than half of the square (``k * k`` pixels, the image's
    outside counting as invalid) valid. ``k`` 1 returns them as they are."""
    if k <= 1:
        return nrm, ok
    if k % 2 == 0:
        raise ValueError(f"smooth_normals: the square must have a centre pixel (an odd size), got {k}")
    summed = torch.nn.functional.avg_pool2d((nrm * ok[..., None]).permute(2, 0, 1)[None], k, 1, k // 2)[0]
    share = torch.nn.functional.avg_pool2d(ok[None, None].to(nrm.dtype), k, 1, k // 2)[0, 0]
    out = summed.permute(1, 2, 0)
    return out / out.norm(dim=-1, keepdim=True).clamp(min=1e-12), ok & (share > 0.5)


def _level_points(depth: torch.Tensor, cam: tuple[float, float, float, float], max_jump: float,
                  smooth: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points ``[H, W, 3]``, normals ``[H, W, 3]`` (averaged over ``smooth`` pixels square:
    :func:`smooth_normals`) and their validity ``[H, W]`` of one pyramid level's depth; ``cam``: that level's
    ``(fx, fy, cx, cy)``."""
    vert = _vertices(depth, *cam)
    nrm, ok = smooth_normals(*_normals(vert, depth, max_jump), smooth)
    return vert, nrm, ok


def _associate(pts: torch.Tensor, pnrm: torch.Tensor, T: torch.Tensor, prev: tuple, cam: tuple, dmax: float,
               pmax: float, min_cos: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Projective data association by tensor ops (the reference of :func:`slam.core.odometry_kernels.associate`):
    the current frame's points ``pts`` / normals ``pnrm`` ``[P, 3]`` (float64, CPU), moved by ``T``, matched with
    the previous level's ``prev = (points, normals, valid)`` at the pixel they project to, kept where the
    point-to-plane distance is below ``dmax``, the points' distance below ``pmax`` and the normals' cosine above
    ``min_cos`` (see :data:`POINT_GATE`).

    Returns ``(idx, tgt, nrm, src)``: indices into ``pts`` of the kept matches, their target points and normals,
    and the moved points (previous camera frame)."""
    vp, np_, okp = prev
    lfx, lfy, lcx, lcy = cam
    H, W = okp.shape
    q = pts @ T[:3, :3].T + T[:3, 3]  # in the previous camera frame
    z = q[:, 2]
    front = z > 1e-6
    u = torch.round(lfx * q[:, 0] / z.clamp(min=1e-6) + lcx).long()
    v = torch.round(lfy * q[:, 1] / z.clamp(min=1e-6) + lcy).long()
    inside = front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    idx = torch.nonzero(inside).flatten()
    ui, vi = u[idx], v[idx]
    good = okp[vi, ui]
    idx, ui, vi = idx[good], ui[good], vi[good]
    tgt, nrm, src = vp[vi, ui], np_[vi, ui], q[idx]
    # close to the target's plane and not far from its point, and the current point's normal (rotated) agreeing
    # with the target's: no matches across surfaces
    d = src - tgt
    close = ((d.norm(dim=-1) < pmax) & ((d * nrm).sum(-1).abs() < dmax)
             & (((pnrm[idx] @ T[:3, :3].T) * nrm).sum(-1) > min_cos))
    return idx[close], tgt[close], nrm[close], src[close]


def _gauss_newton_step(src: torch.Tensor, tgt: torch.Tensor, nrm: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """One robust (Huber) Gauss-Newton step on the point-to-plane residuals of the matches: the ``[6]`` twist
    that moves ``src`` onto the planes of ``tgt`` / ``nrm``, and the residuals ``[M]`` before it."""
    r = ((src - tgt) * nrm).sum(-1)
    J = torch.cat((torch.linalg.cross(src, nrm, dim=-1), nrm), -1)  # d r / d (w, t), left twist
    scale = 1.4826 * r.abs().median().clamp(min=1e-4)
    w = 1.0 / torch.clamp(r.abs() / (1.345 * scale), min=1.0)  # Huber weights
    Jw = (J * w[:, None]).T
    A = Jw @ J
    b = -Jw @ r
    xi = torch.linalg.solve(A + 1e-6 * torch.eye(6, dtype=A.dtype), b)
    return xi, r


@torch.no_grad()
def icp_relative_pose(
    depth_prev: torch.Tensor,
    depth_cur: torch.Tensor,
    intrinsics,
    init: torch.Tensor | None = None,
    levels: tuple[int, ...] | None = None,
    iters: tuple[int, ...] = (10, 5),
    max_dist: tuple[float, ...] = (0.10, 0.05),
    min_cos: float = 0.8,
    min_inliers: float = 0.3,
    max_jump: float = 0.1,
    smooth: int = 3,
    kernel: bool = True,
) -> ICPResult:
    """Estimate the relative pose of ``depth_cur``'s camera in ``depth_prev``'s camera frame.

    Args:
        depth_prev, depth_cur: ``[H, W]`` metres (0 invalid), same size and camera.
        intrinsics: ``slam.data.Intrinsics`` of that image.
        init: ``[4, 4]`` starting relative pose (default identity), e.g. the constant-velocity prediction.
        levels: downsampling factor per pyramid level, coarse first (default :func:`pyramid` of the image size);
            ``iters`` Gauss-Newton steps per level;
            ``max_dist`` metres, the largest distance of a correspondence's point to its target's plane at each
            level (its points at most :data:`POINT_GATE` times that apart).
        min_cos: smallest cosine between corresponding normals.
        min_inliers: share of the current frame's valid points that must find a correspondence (finest level).
        max_jump: relative depth jump between neighbours beyond which no normal is computed (depth edges).
        smooth: normals averaged over this many pixels square (:func:`smooth_normals`; 1: central differences
            alone; raw normals of far, noisy depth tilt at random: docs/robustness.md, "Depth ICP's normals").
        kernel: numba kernels (:mod:`slam.core.odometry_kernels`: the same formulas, the sums in another order, the
            pose to the last bits of a double); False: tensor ops, the reference.

    Returns:
        :class:`ICPResult`.
    """
    if depth_prev.dim() != 2 or depth_prev.shape != depth_cur.shape:
        raise ValueError(f"icp_relative_pose: depths must be [H, W] of one size, got {tuple(depth_prev.shape)} and "
                         f"{tuple(depth_cur.shape)}")
    if smooth < 1 or smooth % 2 == 0:
        raise ValueError(f"icp_relative_pose: smooth must be 1 or an odd number of pixels, got {smooth}")
    dt = torch.float64
    if levels is None:
        levels = pyramid(*depth_cur.shape)
    T = (torch.eye(4, dtype=dt) if init is None else init.detach().to("cpu", dt)).clone()
    dp, dc = depth_prev.detach().to("cpu", dt), depth_cur.detach().to("cpu", dt)
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    if kernel:
        from slam.core.odometry_kernels import register  # numba compiles (or loads its cache) on first use only

        inl, rmse, failed = register(dp.numpy(), dc.numpy(), T.numpy(), (fx, fy, cx, cy), levels, iters, max_dist,
                                     POINT_GATE, min_cos, max_jump, smooth)
    else:
        T, inl, rmse, failed = _register_reference(dp, dc, T, (fx, fy, cx, cy), levels, iters, max_dist, min_cos,
                                                   max_jump, smooth)
    ok = not failed and inl >= min_inliers and rmse < max_dist[-1]
    return ICPResult(T.float(), float(inl), rmse, bool(ok and torch.isfinite(T).all()))


def _register_reference(dp, dc, T, intr, levels, iters, max_dist, min_cos, max_jump, smooth):
    """The registration by tensor ops, the reference of :mod:`slam.core.odometry_kernels`: float64 depths
    ``[H, W]``, ``T [4, 4]`` the start, ``intr`` ``(fx, fy, cx, cy)`` of the full image. Returns ``(T, inlier
    share, RMS residual in metres, failed)``; failed: a level or a step had fewer than 50 points or matches."""
    fx, fy, cx, cy = intr
    inl, rmse = 0.0, float("inf")
    for f, n_it, dmax in zip(levels, iters, max_dist):
        p_depth, c_depth = _downsample(dp, f), _downsample(dc, f)
        # pixel (u, v) of the level sits at (f u, f v) of the full image
        cam = (fx / f, fy / f, cx / f, cy / f)
        vp, np_, okp = _level_points(p_depth, cam, max_jump, smooth)
        vc, nc, okc = _level_points(c_depth, cam, max_jump, smooth)
        pts, pnrm = vc[okc], nc[okc]  # [P, 3] current camera frame
        if pts.shape[0] < 50 or int(okp.sum()) < 50:
            return T, 0.0, float("inf"), True
        for _ in range(n_it):
            idx, tgt, nrm, src = _associate(pts, pnrm, T, (vp, np_, okp), cam, dmax, POINT_GATE * dmax, min_cos)
            if idx.numel() < 50:
                return T, idx.numel() / max(pts.shape[0], 1), float("inf"), True
            xi, r = _gauss_newton_step(src, tgt, nrm)
            T = exp_se3(xi) @ T
            inl = idx.numel() / pts.shape[0]
            rmse = float(torch.sqrt((r**2).mean()))
            if float(xi.norm()) < 1e-5:
                break
    return T, float(inl), rmse, False


# normals averaged over this many pixels square (coarsest level) for the observability check: raw, a flat wall
# looks as constrained in its sliding directions as a furnished room (eigenvalue ratios 2e-3 to 1e-2); averaged, the
# wall's fall to 1e-5 to 2e-4, the TUM office's weakest stays above 3e-3
# (docs/robustness.md, "Depth ICP holds what it cannot see")
SMOOTH_NORMALS = 5


def normal_matrix(depth: torch.Tensor, intrinsics) -> torch.Tensor | None:
    """How firmly a depth image's geometry holds each direction of camera motion: ``[6, 6]`` float64, the mean of
    ``J^T J`` over the image's points with ``J = [p x n, n]`` (point ``p`` and normal ``n`` in this camera's frame,
    metres; left twists (rotation, translation) in this camera's frame), normals averaged over
    :data:`SMOOTH_NORMALS` pixels square at the coarsest pyramid level; None with fewer than 50 such points.

    Args:
        depth: ``[H, W]`` metres (0 invalid); intrinsics: its ``slam.data.Intrinsics``.
    """
    f = pyramid(*depth.shape)[0]
    d = _downsample(depth.detach().to("cpu", torch.float64), f)
    vert = _vertices(d, intrinsics.fx / f, intrinsics.fy / f, intrinsics.cx / f, intrinsics.cy / f)
    nrm, ok = smooth_normals(*_normals(vert, d, 0.1), SMOOTH_NORMALS)
    if int(ok.sum()) < 50:
        return None
    p, n = vert[ok], nrm[ok]
    J = torch.cat((torch.linalg.cross(p, n, dim=-1), n), -1)
    return J.T @ J / J.shape[0]


def unobserved_directions(depth: torch.Tensor, intrinsics, below: float) -> torch.Tensor:
    """The directions of camera motion that the geometry of a depth image does not observe: ``[6, m]`` orthonormal
    twists (rotation, translation; left twists in this camera's frame), m = 0 to 6.

    A direction is unobserved when its eigenvalue of :func:`normal_matrix` is below ``below`` times the largest.
    Facing a single plane that is the slide along it and the turn about its normal (3 directions); a room, a
    corner or a floor with furniture has none.

    Args:
        depth: ``[H, W]`` metres (0 invalid); intrinsics: its ``slam.data.Intrinsics``.
        below: eigenvalue ratio under which a direction counts as unobserved.
    """
    N = normal_matrix(depth, intrinsics)
    if N is None:
        return torch.zeros(6, 0, dtype=torch.float64)
    lam, vec = torch.linalg.eigh(N)
    return vec[:, lam < below * lam[-1]]


def hold_unobserved(relative: torch.Tensor, hold: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """``relative`` with its motion away from ``hold`` (both ``[4, 4]`` poses in the reference camera's frame) taken
    out along ``directions`` ``[6, m]`` (:func:`unobserved_directions` of the reference image): there the result
    is ``hold``'s, elsewhere ``relative``'s.

    Why: ICP keeps its start's motion along a direction depth does not observe; from a constant-velocity start an
    error there becomes the next velocity and grows (docs/robustness.md, "Depth ICP holds what it cannot see").
    """
    if directions.shape[1] == 0:
        return relative
    rel, held = relative.double(), hold.double()
    D = rel @ torch.linalg.inv(held)  # a left twist, as ICP's steps apply theirs
    d = torch.cat((rotation_vector(D[:3, :3]), D[:3, 3]))
    d = d - directions @ (directions.T @ d)
    return (exp_se3(d) @ held).to(relative.dtype)
