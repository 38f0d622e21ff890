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
when a step moves the camera by less than ``gn_step_m`` metres and ``gn_step_deg`` degrees, when the normal
equations predict it lowers the loss by less than ``gn_min_decrease`` of it (the next one would lower it by a fraction
of that again: Gauss-Newton near its optimum), or after ``iters`` evaluations. Rays are kept where the starting
pose sees their surface inside the box, and the outlier rule (``outlier_factor``) is applied once, at the start.

With ``tracking.gn_hessian: first`` only a round's first evaluation assembles ``H``; later ones bring ``b`` alone,
half the loss's gradient in the tangent from one backward pass (:func:`_gradient_terms`), and the steps keep the
first ``H``. Either way the evaluation that ends a round (a small step, or the last allowed) computes the loss alone.

With ``tracking.gn_prior`` = kappa > 0 the solve minimises the loss plus ``e^T P e``, ``e`` the tangent from the
start pose (the ICP start) and ``P`` kappa times the start's mean curvature per group of axes (rotation,
translation), the same on each of the camera's own axes of a group (``tracking.gn_prior_shape``,
:func:`slam.engine.gn_prior.prior_metric`). One draw of pixels constrains some directions barely, and there its
optimum is mostly noise (docs/slam.md, "A second-order tracker"); the prior keeps the pose near the start in those
directions and leaves the well-constrained ones to the data. The loss reported is the
data term alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

import tdfields
from slam.core import fused_render
from slam.core.camera import pixel_directions, sample_pixels
from slam.core.losses import sdf_regions, total_loss, tracking_inliers
from slam.core.pose import exp_se3, matrix_to_pose, normalize_pose, pose_to_matrix
from slam.core.rendering import color_sum, composite, ray_box_exit, sample_colors
from slam.core.sampling import sample_depth_rays
from slam.engine.gn_prior import prior_metric
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


def _render(scene, pts: torch.Tensor, rays: _Rays, cutoff: float, fused: bool):
    """SDF ``[R, N]``, colour ``[R, N, 3]`` at the points, and the depth / colour composited from detached copies
    of them (the leaves ``s_l``, ``rgb_l``), so the compositing can be differentiated on its own (with ``fused``,
    by :mod:`slam.core.fused_render` where it can run)."""
    R, N, _ = pts.shape
    flat = pts.reshape(-1, 3)
    s = scene.sdf(flat).reshape(R, N)
    s_l = s.detach().requires_grad_(True)
    fused = fused and fused_render.eligible(s_l, constant=(rays.z,))
    w, depth = composite(s_l, scene.beta, rays.z, fused)
    rgb = sample_colors(flat, w, scene.rgb, cutoff)
    rgb_l = rgb.detach().requires_grad_(True)
    color = color_sum(w, rgb_l, fused)
    return s, rgb, s_l, rgb_l, w, depth, color


def _loss(s, depth, color, rays: _Rays, cfg) -> torch.Tensor:
    return total_loss(s, rays.z, depth, color, rays.D, rays.C, cfg.scene.truncation, cfg.tracking.weights,
                      fused=cfg.rendering.fused)[0]


def _jacobian_terms(pts, s, rgb, s_l, rgb_l, w, depth, color, rays: _Rays, cfg):
    """``(H [6, 6], b [6])`` of the weighted normal equations at these points (float64).

    The rows are assembled without gathering each region's samples: every sample gets one row ``[p x g, g]`` and one
    weight, zero outside the SDF regions, the band's ``T`` folded into its weight and residual
    (:func:`_sdf_weights`), so ``H = A^T diag(W) A`` is one product over all samples. The colour channels share
    one stacked assembly."""
    T, wt = cfg.scene.truncation, cfg.tracking.weights
    R, N = rays.z.shape
    gs = torch.autograd.grad(s, pts, torch.ones_like(s), retain_graph=True)[0]  # [R, N, 3] d s / d p
    d_ds = torch.autograd.grad(depth, s_l, torch.ones_like(depth), retain_graph=True)[0]  # [R, N]
    p = pts.detach()
    W, r = _sdf_weights(s.detach(), rays, T, wt)
    A = torch.cat((torch.cross(p, gs, dim=-1), gs), -1).reshape(R * N, 6).double()
    H = A.T @ (W.reshape(-1, 1) * A)
    b = A.T @ (W * r).reshape(-1)
    ray_rows, ray_res, ray_w = [], [], []
    if wt.depth:
        ray_rows.append(d_ds[..., None] * gs)
        ray_res.append(depth.detach() - rays.D)
        ray_w.append(wt.depth / R)
    if wt.color:
        for c in range(3):
            dc_ds = torch.autograd.grad(color[:, c], s_l, torch.ones_like(depth), retain_graph=True)[0]
            grgb = torch.autograd.grad(rgb[..., c], pts, torch.ones_like(rgb[..., c]), retain_graph=c < 2)[0]
            ray_rows.append(dc_ds[..., None] * gs + w.detach()[..., None] * grgb)
            ray_res.append(color.detach()[:, c] - rays.C[:, c])
            ray_w.append(wt.color / (3 * R))
    if ray_rows:
        g = torch.stack(ray_rows)  # [K, R, N, 3]: each per-ray residual's gradient at its ray's points
        J = torch.cat((torch.cross(p.expand_as(g), g, dim=-1).sum(2), g.sum(2)), -1).double()  # [K, R, 6]
        Wr = torch.tensor(ray_w, dtype=torch.float64, device=J.device)[:, None, None]
        H = H + (J * Wr).reshape(-1, 6).T @ J.reshape(-1, 6)
        b = b + (J * (Wr * torch.stack(ray_res).double()[..., None])).reshape(-1, 6).sum(0)
    return H, b


def _sdf_weights(sd: torch.Tensor, rays: _Rays, T: float, wt) -> tuple[torch.Tensor, torch.Tensor]:
    """``(W, r)`` ``[R, N]`` float64 per-sample weight and residual of the three SDF terms, for rows ``[p x g, g]``
    with ``g`` the SDF's gradient: free space ``s - 1`` at ``fs / n_front``; the centre and the tail ``z + s T - D``,
    whose gradient is ``T g``, at ``T^2 lambda / n`` with the residual divided by ``T`` (so ``W r`` carries one
    ``T``); zero elsewhere (behind the band, and a term with no samples or no weight)."""
    front, center, tail = sdf_regions(rays.z, rays.D, T)
    sd, z, Dm = sd.double(), rays.z.double(), rays.D.double()[:, None]
    W = torch.zeros_like(sd)
    for mask, lam, scale in ((front, wt.fs, 1.0), (center, wt.center, T), (tail, wt.tail, T)):
        n = int(mask.sum())
        if n and lam:
            W = W + mask.double() * (lam / n * scale * scale)
    band = torch.where(front, sd - 1.0, (z + sd * T - Dm) / T)
    return W, torch.where(W > 0, band, torch.zeros_like(band))


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


def _gradient_terms(loss, pts, s, rgb, s_l, rgb_l) -> torch.Tensor:
    """``b [6]`` (float64) of the normal equations alone: half the gradient of ``loss`` (a scalar tensor with its
    graph) in the pose tangent, from one backward pass to the points (the compositing's, then the SDF's and the
    colour's field backward together), where :func:`_jacobian_terms` takes one per residual kind. ``b = J^T W r``
    because the loss is ``r^T W r``."""
    g_s, g_sl, g_rgb = torch.autograd.grad(loss, (s, s_l, rgb_l), allow_unused=True)
    g_s = torch.zeros_like(s) if g_s is None else g_s  # the SDF reaches the loss directly and through compositing
    if g_sl is not None:
        g_s = g_s + g_sl
    outs, grads = [s], [g_s]
    if g_rgb is not None and rgb.requires_grad:
        outs.append(rgb)
        grads.append(g_rgb)
    g = torch.autograd.grad(outs, pts, grads)[0].reshape(-1, 3)  # [R N, 3] d loss / d p
    p = pts.detach().reshape(-1, 3)
    return 0.5 * torch.cat((torch.cross(p, g, dim=-1).sum(0), g.sum(0))).double()


def _evaluate(scene, T, rays, cfg, need: str = "loss"):
    """``(loss, rendered depth [R], terms)`` at camera-to-world ``T`` ``[4, 4]``; ``terms`` by ``need``: "loss"
    None, "gradient" ``(None, b)``, "hessian" ``(H, b)`` (None too when the loss is not finite)."""
    pts = _points(T, rays).requires_grad_(need != "loss")
    with torch.set_grad_enabled(need != "loss"):
        out = _render(scene, pts, rays, cfg.rendering.color_cutoff, cfg.rendering.fused)
        s, rgb, s_l, rgb_l, w, depth, color = out
        # the gradient mode differentiates the loss itself; the others need its value only
        loss_t = _loss(s, depth, color, rays, cfg) if need == "gradient" else _loss(
            s.detach(), depth.detach(), color.detach(), rays, cfg)
        loss = float(loss_t.detach())
        if need == "loss" or not math.isfinite(loss):
            return loss, depth.detach(), None
        if need == "gradient":
            return loss, depth.detach(), (None, _gradient_terms(loss_t, pts, s, rgb, s_l, rgb_l))
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
        for _ in range(tc.gn_rounds):
            last = _solve_round(scene, color, depth, intrinsics, T, cfg, generator, iters)
            total += last[3]
            if last[0] is None:
                break
            done, T = last, last[0]
    if done is None:
        return TrackResult(init_pose.clone(), float("nan"), False, last[2], total, last[4])
    T, loss, message, _, inliers = done  # a later round without rays or a finite loss keeps the earlier result
    return TrackResult(normalize_pose(matrix_to_pose(T.cpu())), loss, True, message, total, inliers)


def _solve_round(scene, color, depth, intrinsics, T, cfg, generator, iters):
    """One Levenberg-Marquardt solve from ``T`` ``[4, 4]`` on a fresh ray set: ``(T, loss, message, evaluations,
    inlier share)``, ``T`` None when no ray set or finite loss was had."""
    tc = cfg.tracking
    rays = _draw_rays(scene, color, depth, intrinsics, T, cfg, generator)
    if rays is None:
        return None, float("nan"), "too few rays with valid depth inside the scene box", 0, float("nan")
    _, rendered, _ = _evaluate(scene, T, rays, cfg)
    # the Adam tracker's guards (slam.engine.tracker._loss_at): a NaN depth makes the outlier rule's median NaN and
    # every ray an outlier, and the normal equations of no ray are no step
    if not bool(torch.isfinite(rendered).all()):
        return None, float("nan"), "non-finite rendered depth", 1, float("nan")
    inl = tracking_inliers(rendered, rays.D, tc.outlier_factor)
    if int(inl.sum()) < 10:
        return None, float("nan"), "too few inlier rays", 1, float(inl.float().mean())
    rays = _Rays(rays.dirs_cam[inl], rays.z[inl], rays.D[inl], rays.C[inl])
    inliers = float(inl.float().mean())
    loss, _, terms = _evaluate(scene, T, rays, cfg, "hessian")
    if terms is None:
        return None, float("nan"), "non-finite tracking loss", 1, inliers
    H, b = terms
    lam, it, message = tc.gn_damping, 2, ""
    P = prior_metric(H, tc.gn_prior, T, tc.gn_prior_shape, depth, intrinsics)
    e = torch.zeros(6, dtype=P.dtype, device=P.device)  # the tangent from the start: the summed steps (small motions)
    data_loss = loss
    eye = torch.eye(6, dtype=P.dtype, device=P.device)
    # gn_hessian "first": later evaluations bring the gradient only and the step keeps the first H (a chord method:
    # the loss still decides every step, and b = 0 where the round ends, whatever H)
    later = "hessian" if tc.gn_hessian == "every" else "gradient"
    while it < iters:
        Hp = H + P
        step = torch.linalg.solve(Hp + lam * torch.diag(torch.diag(Hp)) + 1e-12 * eye, -(b + P @ e))
        T_new = exp_se3(step.to(T.dtype)) @ T
        it += 1
        small = (float(step[3:].norm()) < tc.gn_step_m and math.degrees(float(step[:3].norm())) < tc.gn_step_deg)
        # the model loss + 2 g^T s + s^T H s (g = b + P e) predicts the step's decrease; under gn_min_decrease of the
        # loss, the next step would move it by noise
        small = small or (tc.gn_min_decrease > 0 and
                          float(-2 * (b + P @ e) @ step - step @ Hp @ step) < tc.gn_min_decrease * loss)
        # a small step ends the round whether it is kept or not, and so does the last evaluation: the loss only
        new_data, _, new_terms = _evaluate(scene, T_new, rays, cfg, "loss" if small or it >= iters else later)
        e_new = e + step
        new_loss = new_data + float(e_new @ P @ e_new)
        if new_loss < loss:  # False for a non-finite loss
            T, loss, lam, e, data_loss = T_new, new_loss, lam / 3.0, e_new, new_data
            if small:
                message = "converged"
                break
            if new_terms is not None:
                H = H if new_terms[0] is None else new_terms[0]
                b = new_terms[1]
        else:
            lam *= 4.0
            if small or lam > 1e4:
                message = "converged" if small else "no step lowers the loss"
                break
    return T, data_loss, message, it, inliers
