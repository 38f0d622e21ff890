"""Second-order tracking: Levenberg-Marquardt on the 6-DoF camera pose (``tracking.optimizer: gauss_newton``).

The tracking loss is a weighted sum of squares (docs/slam.md, "The pipeline (as implemented)"): per sample the free-space residual
``s - 1`` and the band residual ``z + s T - D``, per ray the depth residual ``d_hat - D`` and three colour
residuals. Each residual depends on the pose only through the points ``p = o + z d`` of its ray, and a pose update
``T <- exp(xi) T`` with ``xi = (omega, v)`` moves a point by ``omega x p + v``, so a residual's Jacobian is
``[p x g, g]`` summed over the points it reads, with ``g`` its gradient with respect to the point. Those gradients
come from four backward passes to the points (the SDF and the three colour channels: the field kernels' coordinate
backward); the compositing in between is differentiated separately and chained (a ray's depth and colour depend on
its own samples only). The normal equations ``(J^T W J + lambda diag) xi = -J^T W r`` (float64, 6 x 6) give the
step; a step that does not lower the loss is refused and the damping raised.

Unlike the Adam tracker (:mod:`slam.engine.tracker`) one set of pixels and one jitter of the samples is drawn per
call, so every evaluation is of the same objective and the loss decides which step to keep. The call stops
when a step moves the camera by less than ``gn_step_m`` metres and ``gn_step_deg`` degrees, or after ``iters``
evaluations. Rays are kept where the starting pose sees their surface inside the box, and the outlier rule
(``outlier_factor``) is applied once, at the start.

With ``tracking.gn_draw: every_step`` (:func:`_solve_incremental`) every evaluation draws fresh pixels at the pose
reached so far and applies the outlier rule to its own rendering, and the steps solve the normal equations of all
the draws together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

import tdfields
from slam.core.camera import pixel_directions, sample_pixels
from slam.core.losses import sdf_regions, total_loss, tracking_inliers
from slam.core.pose import exp_se3, matrix_to_pose, normalize_pose, pose_to_matrix
from slam.core.rendering import composite_weights, ray_box_exit, sample_depth_rays, sdf_to_alpha
from slam.engine.state import TrackResult


@dataclass
class _Rays:
    """The call's fixed rays: camera-frame directions ``[R, 3]``, sample depths ``z [R, N]``, measured depth
    ``D [R]`` and colour ``C [R, 3]``."""

    dirs_cam: torch.Tensor
    z: torch.Tensor
    D: torch.Tensor
    C: torch.Tensor


def _points(T: torch.Tensor, rays: _Rays) -> torch.Tensor:
    """``[R, N, 3]`` world points of the samples for camera-to-world ``T`` ``[4, 4]``."""
    dirs = rays.dirs_cam @ T[:3, :3].T
    return T[:3, 3] + dirs[:, None, :] * rays.z[..., None]


def _render(scene, pts: torch.Tensor, rays: _Rays, cutoff: float):
    """SDF ``[R, N]``, colour ``[R, N, 3]`` at the points, and the depth / colour composited from detached copies
    of them (the leaves ``s_l``, ``rgb_l``), so the compositing can be differentiated on its own."""
    R, N, _ = pts.shape
    flat = pts.reshape(-1, 3)
    s = scene.sdf(flat).reshape(R, N)
    s_l = s.detach().requires_grad_(True)
    w = composite_weights(sdf_to_alpha(s_l, scene.beta))
    keep = (w.detach() > cutoff).reshape(-1) if cutoff > 0 else None
    if keep is None:
        rgb = scene.rgb(flat).reshape(R, N, 3)
    else:
        rgb = flat.new_zeros(R * N, 3)
        rgb[keep] = scene.rgb(flat[keep])
        rgb = rgb.reshape(R, N, 3)
    rgb_l = rgb.detach().requires_grad_(True)
    depth = (w * rays.z).sum(-1)
    color = (w[..., None] * rgb_l).sum(-2)
    return s, rgb, s_l, rgb_l, w, depth, color


def _loss(s, depth, color, rays: _Rays, cfg) -> torch.Tensor:
    return total_loss(s, rays.z, depth, color, rays.D, rays.C, cfg.scene.truncation, cfg.tracking.weights)[0]


def _jacobian_terms(pts, s, rgb, s_l, rgb_l, w, depth, color, rays: _Rays, cfg, keep=None):
    """``(H [6, 6], b [6])`` of the weighted normal equations at these points (float64), of the rays ``keep``
    ``[R]`` (bool) only when given (the rays are differentiated together, then the kept ones are used)."""
    T, wt = cfg.scene.truncation, cfg.tracking.weights
    sub = (lambda x: x) if keep is None else (lambda x: x[keep])
    gs = torch.autograd.grad(s, pts, torch.ones_like(s), retain_graph=True)[0]  # [R, N, 3] d s / d p
    d_ds = torch.autograd.grad(depth, s_l, torch.ones_like(depth), retain_graph=True)[0]  # [R, N]
    if keep is not None:
        rays = _Rays(rays.dirs_cam[keep], rays.z[keep], rays.D[keep], rays.C[keep])
        gs, d_ds = gs[keep], d_ds[keep]
    R, N = rays.z.shape
    p, sd, wd = sub(pts.detach()), sub(s.detach()), sub(w.detach())
    rows, resid, weights = [], [], []
    Dm = rays.D[:, None]
    front, center, tail = sdf_regions(rays.z, rays.D, T)
    for mask, r, g, lam in ((front, sd - 1.0, gs, wt.fs), (center, rays.z + sd * T - Dm, T * gs, wt.center),
                            (tail, rays.z + sd * T - Dm, T * gs, wt.tail)):
        n = int(mask.sum())
        if n and lam:
            rows.append(torch.cat((torch.cross(p[mask], g[mask], dim=-1), g[mask]), -1))
            resid.append(r[mask])
            weights.append(torch.full((n,), lam / n, dtype=sd.dtype))
    if wt.depth:
        gd = d_ds[..., None] * gs
        rows.append(torch.cat((torch.cross(p, gd, dim=-1).sum(1), gd.sum(1)), -1))
        resid.append(sub(depth.detach()) - rays.D)
        weights.append(torch.full((R,), wt.depth / R, dtype=sd.dtype))
    if wt.color:
        for c in range(3):
            dc_ds = sub(torch.autograd.grad(color[:, c], s_l, torch.ones_like(depth), retain_graph=True)[0])
            grgb = sub(torch.autograd.grad(rgb[..., c], pts, torch.ones_like(rgb[..., c]), retain_graph=c < 2)[0])
            gc = dc_ds[..., None] * gs + wd[..., None] * grgb
            rows.append(torch.cat((torch.cross(p, gc, dim=-1).sum(1), gc.sum(1)), -1))
            resid.append(sub(color.detach())[:, c] - rays.C[:, c])
            weights.append(torch.full((R,), wt.color / (3 * R), dtype=sd.dtype))
    J, r, W = torch.cat(rows).double(), torch.cat(resid).double(), torch.cat(weights).double()
    return J.T @ (W[:, None] * J), J.T @ (W * r)


def _draw_rays(scene, color, depth, intrinsics, T, cfg, generator) -> _Rays | None:
    """The call's pixels: drawn once, kept where the start pose sees their surface inside the box."""
    tc = cfg.tracking
    H, W = depth.shape
    v, u = sample_pixels(H, W, tc.pixels, tc.ignore_edge[0], tc.ignore_edge[1], generator)
    v, u = v.to(depth.device), u.to(depth.device)
    D, C = depth[v, u], color[v, u]
    dirs_cam = pixel_directions(u.to(D.dtype), v.to(D.dtype), intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                intrinsics.cy)
    keep = (D > 0) & (ray_box_exit(T[:3, 3].expand(len(D), 3), dirs_cam @ T[:3, :3].T, scene.aabb) >= D)
    if int(keep.sum()) < 10:
        return None
    # jittered once per call (rendering.perturb): every evaluation sees the same samples, and the discretisation of
    # the composited depth does not bias the optimum the same way in every frame
    z = sample_depth_rays(D[keep], cfg.rendering.n_stratified, cfg.rendering.n_importance, cfg.scene.truncation,
                          perturb=cfg.rendering.perturb, generator=generator)
    return _Rays(dirs_cam[keep], z, D[keep], C[keep])


def _evaluate(scene, T, rays, cfg, jacobian: bool, outliers: bool = False):
    """``(loss, rendered depth [R], (H, b) or None)`` at camera-to-world ``T``; with ``outliers`` the outlier rule
    (``tracking.outlier_factor``) is applied to this evaluation's own rendering, and the loss and the normal
    equations are of the inlier rays (then also returns their share as a fourth value)."""
    pts = _points(T, rays).requires_grad_(jacobian)
    with torch.set_grad_enabled(jacobian):
        out = _render(scene, pts, rays, cfg.rendering.color_cutoff)
        s, rgb, s_l, rgb_l, w, depth, color = out
        if outliers:
            keep = tracking_inliers(depth.detach(), rays.D, cfg.tracking.outlier_factor)
            kept = _Rays(rays.dirs_cam[keep], rays.z[keep], rays.D[keep], rays.C[keep])
            share = float(keep.float().mean())
            if int(keep.sum()) < 10:
                return float("nan"), depth.detach(), None, share
            loss = float(_loss(s.detach()[keep], depth.detach()[keep], color.detach()[keep], kept, cfg))
            if not jacobian or not math.isfinite(loss):
                return loss, depth.detach(), None, share
            return loss, depth.detach(), _jacobian_terms(pts, s, rgb, s_l, rgb_l, w, depth, color, rays, cfg,
                                                         keep), share
        loss = float(_loss(s.detach(), depth.detach(), color.detach(), rays, cfg))
        if not jacobian or not math.isfinite(loss):
            return loss, depth.detach(), None
        return loss, depth.detach(), _jacobian_terms(pts, s, rgb, s_l, rgb_l, w, depth, color, rays, cfg)


def track_frame_gn(scene, color: torch.Tensor, depth: torch.Tensor, intrinsics, init_pose: torch.Tensor, cfg,
                   generator: torch.Generator, iters: int | None = None) -> TrackResult:
    """Estimate the camera-to-world pose of one frame by Levenberg-Marquardt (same arguments and result as
    :func:`slam.engine.tracker.track_frame`; ``iters`` counts loss evaluations per round, at most
    ``tracking.gn_iters``). With ``tracking.gn_rounds`` > 1 each later round draws fresh pixels and applies the
    outlier rule again at the pose the previous round reached, and solves from there."""
    tc = cfg.tracking
    iters = tc.gn_iters if iters is None else iters
    T = pose_to_matrix(init_pose.to(depth.device).float()).detach()
    done, last, total = None, None, 0
    with tdfields.frozen(scene):
        if tc.gn_draw == "every_step":
            T, loss, message, n, inliers = _solve_incremental(scene, color, depth, intrinsics, T, cfg, generator,
                                                              iters)
            if T is None:
                return TrackResult(init_pose.clone(), float("nan"), False, message, n)
            return TrackResult(normalize_pose(matrix_to_pose(T.cpu())), loss, True, message, n, inliers)
        for _ in range(tc.gn_rounds):
            last = _solve_round(scene, color, depth, intrinsics, T, cfg, generator, iters)
            total += last[3]
            if last[0] is None:
                break
            done, T = last, last[0]
    if done is None:
        return TrackResult(init_pose.clone(), float("nan"), False, last[2], total)
    T, loss, message, _, inliers = done  # a later round without rays or a finite loss keeps the earlier result
    return TrackResult(normalize_pose(matrix_to_pose(T.cpu())), loss, True, message, total, inliers)


def _solve_round(scene, color, depth, intrinsics, T, cfg, generator, iters):
    """One Levenberg-Marquardt solve from ``T`` ``[4, 4]`` on a fresh ray set: ``(T, loss, message, evaluations,
    inlier share)``, ``T`` None when no ray set or finite loss was had."""
    tc = cfg.tracking
    rays = _draw_rays(scene, color, depth, intrinsics, T, cfg, generator)
    if rays is None:
        return None, float("nan"), "too few rays with valid depth inside the scene box", 0, float("nan")
    _, rendered, _ = _evaluate(scene, T, rays, cfg, jacobian=False)
    inl = tracking_inliers(rendered, rays.D, tc.outlier_factor)
    rays = _Rays(rays.dirs_cam[inl], rays.z[inl], rays.D[inl], rays.C[inl])
    inliers = float(inl.float().mean())
    loss, _, terms = _evaluate(scene, T, rays, cfg, jacobian=True)
    if terms is None:
        return None, float("nan"), "non-finite tracking loss", 1, inliers
    lam, it, message = tc.gn_damping, 2, ""
    while it < iters:
        H, b = terms
        step = torch.linalg.solve(H + lam * torch.diag(torch.diag(H)) + 1e-12 * torch.eye(6, dtype=H.dtype), -b)
        T_new = exp_se3(step.to(T.dtype)) @ T
        it += 1
        new_loss, _, new_terms = _evaluate(scene, T_new, rays, cfg, jacobian=True)
        small = (float(step[3:].norm()) < tc.gn_step_m and math.degrees(float(step[:3].norm())) < tc.gn_step_deg)
        if new_terms is not None and new_loss < loss:
            T, loss, terms, lam = T_new, new_loss, new_terms, lam / 3.0
            if small:
                message = "converged"
                break
        else:
            lam *= 4.0
            if small or lam > 1e4:
                message = "converged" if small else "no step lowers the loss"
                break
    return T, loss, message, it, inliers


# a draw whose own step is longer than this is taken as "far from the optimum": the sums restart from it (the
# composited depth is linear only within a few mm of a surface, tests/slam/engine/test_gauss_newton.py)
ACCUMULATE_WITHIN_M, ACCUMULATE_WITHIN_DEG = 0.005, 0.25


def _solve(H: torch.Tensor, b: torch.Tensor, damping: float) -> torch.Tensor:
    """The damped Gauss-Newton step ``[6]`` of the normal equations ``H xi = -b``."""
    return torch.linalg.solve(H + damping * torch.diag(torch.diag(H)) + 1e-12 * torch.eye(6, dtype=H.dtype), -b)


def _large(step: torch.Tensor) -> bool:
    return float(step[3:].norm()) > ACCUMULATE_WITHIN_M or math.degrees(float(step[:3].norm())) > ACCUMULATE_WITHIN_DEG


def _solve_incremental(scene, color, depth, intrinsics, T, cfg, generator, iters):
    """Incremental Gauss-Newton (``tracking.gn_draw: every_step``): every evaluation draws fresh pixels and a
    fresh jitter at the current pose, applies the outlier rule to its own rendering and adds its normal equations,
    moved to the current pose to first order (``b_j + H_j (x - x_j)``, ``x`` the summed steps from the start), to
    those of the earlier draws; each step solves the sum. A draw whose own step would be longer than
    ``ACCUMULATE_WITHIN_M`` / ``_DEG`` restarts the sums (far from the optimum the earlier linearisations do not
    hold). So the pose converges to the optimum of all the draws
    together (``iters`` x ``tracking.pixels`` pixels, as Adam sees across its iterations) instead of one draw's,
    and no evaluation is spent on a refused step. The last step is solved after the last evaluation; the loss
    reported is that evaluation's. Returns ``(T or None, loss, message, evaluations, inlier share)``."""
    tc = cfg.tracking
    Hs = torch.zeros(6, 6, dtype=torch.float64)
    g0 = torch.zeros(6, dtype=torch.float64)  # sum of b_j - H_j x_j
    x = torch.zeros(6, dtype=torch.float64)
    loss, inliers, message, n, ok = float("nan"), float("nan"), "", 0, False
    while n < iters:
        rays = _draw_rays(scene, color, depth, intrinsics, T, cfg, generator)
        if rays is None:
            message = "too few rays with valid depth inside the scene box"
            break
        new_loss, _, terms, share = _evaluate(scene, T, rays, cfg, jacobian=True, outliers=True)
        n += 1
        if terms is None:
            message = "too few inlier rays" if share * len(rays.D) < 10 else "non-finite tracking loss"
            break
        loss, inliers, ok = new_loss, share, True
        H, b = terms
        if _large(_solve(H, b, tc.gn_damping)):
            # still far from the optimum: the earlier draws' linearisations do not hold here, start the sums anew
            Hs, g0 = H, b - H @ x
        else:
            Hs, g0 = Hs + H, g0 + b - H @ x
        step = _solve(Hs, g0 + Hs @ x, tc.gn_damping)
        x = x + step
        T = exp_se3(step.to(T.dtype)) @ T
        if float(step[3:].norm()) < tc.gn_step_m and math.degrees(float(step[:3].norm())) < tc.gn_step_deg:
            message = "converged"
            break
    if not ok:
        return None, float("nan"), message or "no evaluation", n, float("nan")
    return T, loss, message, n, inliers
