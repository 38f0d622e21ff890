"""Tracking (docs/slam.md, "The pipeline (as implemented)", Tracking): optimise the current camera pose against the
frozen map.

A fresh Adam (betas 0.5, 0.999) over the quaternion (``lr_r``) and translation (``lr_t``); every iteration draws
new pixels; the loss at the pose *before* each step is recorded and the best one is returned (best-loss
selection). ESLAM runs a fixed number of iterations; with ``tracking.patience = N`` (ours) the call stops once
``N`` iterations in a row found no loss lower than the best by ``min_improvement`` (relative), after at least
``min_iters``. The scene is held in :func:`tdfields.frozen` for the duration, so backward reaches
only the pose and the fields may cache what they derive from the map for this call (never across calls). A
non-finite loss ends the optimisation; if no finite loss was seen the caller falls back.
"""

from __future__ import annotations

import torch

import tdfields
from slam.config import Config
from slam.core.losses import color_loss, total_loss, tracking_inliers
from slam.core.optim import VectorAdam
from slam.core.pose import normalize_pose, pose_to_matrix
from slam.core.camera import pixel_directions, sample_pixels
from slam.core.rendering import camera_rays, ray_box_exit, render_pixels, render_rays
from slam.engine.gauss_newton import track_frame_gn
from slam.engine.state import TrackResult

__all__ = ["TrackResult", "evaluate_pose", "track_frame", "track_on_color"]


def _loss_at(scene, color, depth, intrinsics, c2w, cfg: Config, v, u, generator, perturb: bool):
    """The tracking loss of the pixels ``(v, u)`` for camera-to-world ``c2w`` ``[4, 4]`` (differentiable in it).

    Returns ``(loss, inlier share, message)``; ``loss`` is None (and ``message`` says why) when too few rays are
    left or the rendering is not finite."""
    tc = cfg.tracking
    rendered = render_pixels(scene, u=u, v=v, depth=depth[v, u], color=color[v, u], c2w=c2w, intrinsics=intrinsics,
                             rendering=cfg.rendering, truncation=cfg.scene.truncation, perturb=perturb,
                             generator=generator, depth_required=True, min_rays=10)
    if rendered is None:
        return None, 0.0, "too few rays with valid depth inside the scene box"
    out, D, C = rendered
    if not bool(torch.isfinite(out.depth).all()):
        return None, 0.0, "non-finite rendered depth"
    inl = tracking_inliers(out.depth, D, tc.outlier_factor)
    if int(inl.sum()) < 10:
        return None, 0.0, "too few inlier rays"
    loss, _ = total_loss(out.sdf, out.z, out.depth, out.color, D, C, cfg.scene.truncation, tc.weights, rows=inl,
                         fused=cfg.rendering.fused)
    return loss, float(inl.float().mean()), ""


def track_frame(
    scene,
    color: torch.Tensor,
    depth: torch.Tensor,
    intrinsics,
    init_pose: torch.Tensor,
    cfg: Config,
    generator: torch.Generator,
    iters: int | None = None,
    patience: int | None = None,
) -> TrackResult:
    """Estimate the camera-to-world pose of one frame.

    Args:
        scene: :class:`slam.model.scene.SceneModel` (frozen here).
        color: ``[H, W, 3]`` RGB in [0, 1]; depth: ``[H, W]`` metres (0 invalid); on the scene's device.
        intrinsics: ``slam.data.Intrinsics`` of the working image.
        init_pose: ``[7]`` (q, t) starting pose.
        cfg: resolved config (``tracking``, ``rendering``, ``scene.truncation``).
        generator: CPU generator for pixel and sample draws.
        iters, patience: override ``tracking.iters`` / ``tracking.patience`` (recovery attempts; with
            ``tracking.optimizer: gauss_newton``, ``iters`` caps its loss evaluations).

    Returns:
        :class:`TrackResult` with the best-loss pose.
    """
    if cfg.tracking.optimizer == "gauss_newton":
        return track_frame_gn(scene, color, depth, intrinsics, init_pose, cfg, generator, iters)
    return _track_adam(scene, color, depth, intrinsics, init_pose, cfg, generator, iters, patience)


def _best_of_adam(pose0: torch.Tensor, lrs: torch.Tensor, loss_at, iters: int, converged=None,
                  name: str = "tracking"):
    """Adam (betas 0.5, 0.999) from ``pose0`` ``[7]`` with per-entry rates ``lrs`` ``[7]``, keeping the pose of the
    lowest loss seen *before* each step (best-loss selection, as ESLAM's tracker).

    ``loss_at(pose) -> (loss or None, extra, message)`` is the loss at the pose (None ends the loop with ``message``);
    ``converged(it, value, best) -> bool``, asked after each loss, ends it early. A non-finite loss or pose ends it
    (the message names the loss ``name``).

    Returns:
        ``(best loss, best pose or None, the best loss's extra, message, iterations run)``.
    """
    pose = pose0.clone().requires_grad_(True)
    opt = VectorAdam(pose, lrs, betas=(0.5, 0.999))
    best_loss, best_pose, best_extra, message, it = float("inf"), None, float("nan"), "", 0
    for it in range(1, iters + 1):
        loss, extra, message = loss_at(pose)
        if loss is None:
            break
        value = float(loss.detach())  # one host sync per iteration
        if not torch.isfinite(loss):
            message = f"non-finite {name} loss"
            break
        done = converged is not None and converged(it, value, best_loss)
        if value < best_loss:
            best_loss, best_pose, best_extra = value, pose.detach().clone(), extra
        if done:
            break  # converged: no better pose for a while (the best one is returned)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if not bool(torch.isfinite(pose).all()):
            message = "non-finite pose update"
            break
    return best_loss, best_pose, best_extra, message, it


def _track_adam(scene, color, depth, intrinsics, init_pose, cfg: Config, generator, iters, patience) -> TrackResult:
    """ESLAM's tracker: Adam over ``(q, t)``, fresh pixels every iteration, the best-loss pose returned."""
    tc = cfg.tracking
    iters, patience = (tc.iters if iters is None else iters), (tc.patience if patience is None else patience)
    device, (H, W) = depth.device, depth.shape
    lrs = torch.tensor([tc.lr_r] * 4 + [tc.lr_t] * 3, dtype=init_pose.dtype, device=device)
    since_best = [0]

    def loss_at(pose):
        v, u = sample_pixels(H, W, tc.pixels, tc.ignore_edge[0], tc.ignore_edge[1], generator)
        return _loss_at(scene, color, depth, intrinsics, pose_to_matrix(pose), cfg, v.to(device), u.to(device),
                        generator, cfg.rendering.perturb)

    def converged(it, value, best):
        since_best[0] = 0 if value < best * (1.0 - tc.min_improvement) else since_best[0] + 1
        return bool(patience) and it >= tc.min_iters and since_best[0] >= patience

    with tdfields.frozen(scene):  # no scene gradients; Six-axis caches its planes for this call only
        best_loss, best_pose, best_inliers, message, it = _best_of_adam(init_pose.to(device), lrs, loss_at, iters,
                                                                        converged)
    if best_pose is None or not bool(torch.isfinite(best_pose).all()):
        return TrackResult(init_pose.clone(), float("nan"), False, message or "no finite pose", it)
    return TrackResult(normalize_pose(best_pose).cpu(), best_loss, True, message, it, best_inliers)


@torch.no_grad()
def evaluate_pose(scene, color, depth, intrinsics, pose: torch.Tensor, cfg: Config, v, u) -> tuple[float, float]:
    """``(loss, inlier share)`` of the pose ``[7]`` on the given pixels without jitter (a fair comparison of
    candidate poses: same pixels, same samples). ``(inf, 0)`` when too few rays remain."""
    with tdfields.frozen(scene):
        loss, inliers, _ = _loss_at(scene, color, depth, intrinsics, pose_to_matrix(pose.to(depth.device)), cfg,
                                    v.to(depth.device), u.to(depth.device), None, False)
    if loss is None or not bool(torch.isfinite(loss)):
        return float("inf"), 0.0
    return float(loss), inliers


# a ray "sees the map" when its compositing weights sum past this: it ends on a surface inside the box, so its
# rendered depth stands in for the missing sensor depth
SEEN = 0.5


@torch.no_grad()
def _rays_that_see_the_map(scene, color, intrinsics, pose, cfg: Config, generator):
    """``(v, u, depth)`` ``[R]`` each: of ``tracking.pixels`` pixels drawn, those whose ray from ``pose`` ends on a
    surface of the map (compositing weights summing past :data:`SEEN`), with the rendered depth (metres; no
    jitter)."""
    tc, r = cfg.tracking, cfg.rendering
    v, u = sample_pixels(color.shape[0], color.shape[1], tc.pixels, tc.ignore_edge[0], tc.ignore_edge[1], generator)
    v, u = v.to(color.device), u.to(color.device)
    dirs_cam = pixel_directions(u.to(color.dtype), v.to(color.dtype), intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                intrinsics.cy)
    origins, dirs = camera_rays(pose_to_matrix(pose), dirs_cam)
    ahead = ray_box_exit(origins, dirs, scene.aabb) > 0
    if int(ahead.sum()) == 0:
        return v[:0], u[:0], origins.new_zeros(0)
    out = render_rays(origins[ahead], dirs[ahead], origins.new_zeros(int(ahead.sum())), scene.sdf, scene.rgb,
                      scene.beta, cfg.scene.truncation, r.n_stratified, r.n_importance, scene.aabb, False, None,
                      r.color_cutoff)
    seen = out.weights.sum(-1) > SEEN
    return v[ahead][seen], u[ahead][seen], out.depth[seen]


def track_on_color(scene, color: torch.Tensor, intrinsics, init_pose: torch.Tensor, cfg: Config,
                   generator: torch.Generator, iters: int | None = None) -> tuple[TrackResult, float]:
    """Track a frame that has no valid depth on its colour alone (ours; docs/robustness.md, "Frames without depth").

    One set of ``tracking.pixels`` pixels is drawn; the map is rendered at ``init_pose`` without jitter, and the
    rays that see a surface (weights summing past 0.5) take the rendered depth as their depth. Adam (as in
    :func:`track_frame`, ``tracking.iters`` steps at ``tracking.lr_r``, whatever ``tracking.optimizer`` says) then
    turns the camera to lower the colour error of those rays, sampled around that depth; the translation stays
    ``init_pose``'s. The best-loss pose is returned.

    Args:
        scene: :class:`slam.model.scene.SceneModel` (frozen here).
        color: ``[H, W, 3]`` RGB in [0, 1] on the scene's device; intrinsics: ``slam.data.Intrinsics``.
        init_pose: ``[7]`` (q, t) starting pose (the motion model's prediction).

    Returns:
        ``(result, loss at init_pose)``: both losses are the mean squared colour error of the same rays without
        jitter, so ``result.loss < loss at init_pose`` says colour moved the pose somewhere better;
        ``result.inliers`` is the share of the pixels that see the map.
    """
    tc = cfg.tracking
    iters = tc.iters if iters is None else iters
    device = color.device
    init_pose = init_pose.to(device)
    with tdfields.frozen(scene):
        v, u, depth = _rays_that_see_the_map(scene, color, intrinsics, init_pose, cfg, generator)
        if v.numel() < 10:
            return TrackResult(init_pose.cpu(), float("nan"), False, "too few rays see the map", 0,
                               v.numel() / tc.pixels), float("nan")
        share = v.numel() / tc.pixels

        def loss_at(pose, perturb):
            return _color_loss(scene, color, intrinsics, v, u, depth, pose, cfg, perturb, generator)

        with torch.no_grad():
            start = _value(loss_at(init_pose, False))
        # the rotation only: one frame's colour pins where the camera looks, but barely how far it moved (the
        # parallax of one frame's motion is small), and moving the translation too doubled the error of dropped
        # frames' motion on the fast dev window (docs/robustness.md, "Frames without depth")
        lrs = torch.tensor([tc.lr_r] * 4 + [0.0] * 3, dtype=init_pose.dtype, device=device)

        def jittered(pose):
            loss = loss_at(pose, cfg.rendering.perturb)
            return loss, None, "" if loss is not None else "too few rays inside the scene box"

        best_loss, best_pose, _, message, it = _best_of_adam(init_pose, lrs, jittered, iters, name="colour")
        if best_pose is None or not bool(torch.isfinite(best_pose).all()):
            return TrackResult(init_pose.cpu(), float("nan"), False, message or "no finite pose", it, share), start
        best_pose = normalize_pose(best_pose)
        with torch.no_grad():  # the same rays as `start`, without jitter: a fair comparison
            final = _value(loss_at(best_pose, False))
    return TrackResult(best_pose.cpu(), final, True, message, it, share), start


def _color_loss(scene, color, intrinsics, v, u, depth, pose, cfg: Config, perturb: bool, generator):
    """Mean squared colour error of the pixels ``(v, u)`` rendered from ``pose`` ``[7]`` with samples around
    ``depth`` ``[R]`` (differentiable in the pose); None when fewer than 10 rays stay in the box."""
    rendered = render_pixels(scene, u=u, v=v, depth=depth, color=color[v, u], c2w=pose_to_matrix(pose),
                             intrinsics=intrinsics, rendering=cfg.rendering, truncation=cfg.scene.truncation,
                             perturb=perturb, generator=generator, depth_required=True, min_rays=10)
    return None if rendered is None else color_loss(rendered[0].color, rendered[2])


def _value(loss) -> float:
    return float("nan") if loss is None else float(loss)
