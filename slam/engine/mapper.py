"""Mapping (docs/slam.md, "The pipeline (as implemented)", Mapping): optimise the scene (and, with BA, the window poses)
on a keyframe window.

The optimiser is rebuilt at every call (Adam, default betas): decoders + beta, geometry and appearance fields
at their own learning rates (x ``lr_first_factor`` on the first frame, which runs ``iters_first`` iterations).
Each iteration draws ``pixels // n_frames`` pixels from every window frame over the full image. The SDF and
depth terms use rays with depth; the colour term every ray whose measured surface is inside the box.
Joint BA (after more than ``ba_min_keyframes`` keyframes) optimises one 7-d pose per window frame except the
oldest (the gauge) and frame 0 (pinned to ground truth).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from slam.config import Config
from slam.engine.keyframes import KeyframeStore, keyframe_matrices, overlapping_keyframes, select_window
from slam.core.losses import total_loss
from slam.core.optim import adam
from slam.core.pose import pose_to_matrix, standardize_quaternion
from slam.core.rendering import camera_rays, pixel_directions, ray_box_exit, render_rays, sample_pixels


@dataclass
class MapResult:
    """``pose``: ``[7]`` (possibly BA-refined) current pose; ``window``: frame positions used; ``loss``: the last
    finite loss; ``ok``: at least one step was taken; ``skipped``: steps skipped for a non-finite loss or
    gradient."""

    pose: torch.Tensor
    window: list[int]
    loss: float
    ok: bool
    skipped: int = 0


class MappingAborted(Exception):
    """A mapping call ended early by its ``should_stop`` (the run is being abandoned)."""


def finite_step(loss: torch.Tensor, params: list[torch.Tensor]) -> bool:
    """Whether ``loss`` and every gradient of ``params`` (after ``loss.backward()``) are finite."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return bool(torch.isfinite(loss))
    norms = torch._foreach_norm(grads)  # one fused pass over the gradients
    return bool(torch.isfinite(loss) & torch.isfinite(torch.stack(norms)).all())


def _normalised(p: torch.Tensor) -> torch.Tensor:
    q = p[..., :4] / p[..., :4].norm(dim=-1, keepdim=True).clamp(min=1e-12)
    return torch.cat((standardize_quaternion(q), p[..., 4:]), -1)


def map_frame(
    scene,
    index: int,
    color: torch.Tensor,
    depth: torch.Tensor,
    pose: torch.Tensor,
    intrinsics,
    keyframes: KeyframeStore,
    cfg: Config,
    generator: torch.Generator,
    first: bool = False,
    should_stop=None,
) -> MapResult:
    """One mapping call for frame ``index``.

    Args:
        scene: :class:`slam.model.scene.SceneModel` (optimised in place).
        color, depth: current frame ``[H, W, 3]`` / ``[H, W]`` on the scene's device.
        pose: ``[7]`` current estimated pose.
        keyframes: the store (refined poses written back when BA runs).
        first: the first-frame warm-up (``iters_first``, learning rates x ``lr_first_factor``).
        should_stop: checked before every iteration; True raises :class:`MappingAborted` (a second Ctrl-C: the
            call's work is thrown away, so the map is left mid-call and must not be saved).

    Returns:
        :class:`MapResult` with the (possibly BA-refined) current pose.
    """
    mc = cfg.mapping
    device = depth.device
    H, W = depth.shape
    T = cfg.scene.truncation
    weights = mc.weights

    # ---- window
    window: list[int] = []
    if not first and len(keyframes) > 0:
        if mc.keyframe_selection == "overlap":
            with torch.no_grad():
                overlap = overlapping_keyframes(
                    depth.cpu(), pose_to_matrix(pose.cpu()), keyframe_matrices(keyframes.poses()),
                    intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, intrinsics.height,
                    intrinsics.width, mc.overlap_pixels, mc.overlap_samples, 20, generator)
        else:
            overlap = torch.ones(len(keyframes), dtype=torch.bool)
        window = select_window(len(keyframes), overlap, mc.window_size, generator)

    colors = [keyframes.frames[i].rgb() for i in window] + [color]
    depths = [keyframes.frames[i].metres() for i in window] + [depth]
    frame_ids = [keyframes.frames[i].index for i in window] + [index]
    poses0 = torch.stack([keyframes.frames[i].pose for i in window] + [pose.cpu()]).to(device)
    colors = torch.stack([c.to(device) for c in colors])  # [F, H, W, 3]
    depths = torch.stack([d.to(device) for d in depths])  # [F, H, W]
    F = len(frame_ids)

    ba = mc.joint_opt and not first and len(keyframes) > mc.ba_min_keyframes
    free = torch.zeros(F, dtype=torch.bool)
    if ba:
        free[1:] = True  # oldest selected frame is the gauge
        free &= torch.tensor([fid != 0 for fid in frame_ids])
    factor = mc.lr_first_factor if first else 1.0
    # the warm-up starts from the random initialisation, where the step scale is ~40x (CP): plain rates there
    groups = scene.param_groups(cfg, factor, "none" if first else mc.lr_scaling)
    cam = None
    if bool(free.any()):
        cam = torch.nn.Parameter(poses0[free].clone())
        groups.append({"params": [cam], "lr": mc.joint_opt_cam_lr})
    opt = adam(groups)
    params = [p for g in groups for p in g["params"]]
    steps = skipped = 0

    per_frame = max(mc.pixels // F, 1)
    iters = mc.iters_first if first else mc.iters
    last = float("nan")
    free_dev = free.to(device)
    for _ in range(iters):
        if should_stop is not None and should_stop():
            raise MappingAborted(f"mapping call of frame {index} aborted")
        if cam is not None:
            poses = poses0.clone()
            poses[free_dev] = cam
        else:
            poses = poses0
        c2w = pose_to_matrix(poses)  # [F, 4, 4]
        v, u = sample_pixels(H, W, per_frame * F, 0, 0, generator)
        fidx = torch.arange(F).repeat_interleave(per_frame)
        v, u, fidx = v.to(device), u.to(device), fidx.to(device)
        D = depths[fidx, v, u]
        C = colors[fidx, v, u]
        dirs_cam = pixel_directions(u.to(D.dtype), v.to(D.dtype), intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                    intrinsics.cy)
        origins, dirs = camera_rays(c2w[fidx], dirs_cam)
        keep = ray_box_exit(origins, dirs, scene.aabb) >= D
        if int(keep.sum()) == 0:
            break
        origins, dirs, D, C = origins[keep], dirs[keep], D[keep], C[keep]
        out = render_rays(origins, dirs, D, scene.sdf, scene.rgb, scene.beta, T, cfg.rendering.n_stratified,
                          cfg.rendering.n_importance, scene.aabb, cfg.rendering.perturb, generator,
                          cfg.rendering.color_cutoff)
        loss, _ = total_loss(out.sdf, out.z, out.depth, out.color, D, C, T, weights)
        opt.zero_grad(set_to_none=True)
        if not bool(torch.isfinite(loss)):
            skipped += 1  # nothing is stepped: the map (and Adam's state) stay as they were
            continue
        loss.backward()
        if not finite_step(loss, params):
            skipped += 1
            opt.zero_grad(set_to_none=True)
            continue
        opt.step()
        steps += 1
        last = float(loss.detach())

    refined = pose
    if steps == 0:
        return MapResult(pose, frame_ids, float("nan"), False, skipped)
    if cam is not None:
        new = _normalised(cam.detach().cpu())
        if bool(torch.isfinite(new).all()):
            free_pos = torch.nonzero(free).flatten().tolist()
            for k, pos in enumerate(free_pos):
                if pos < len(window):
                    keyframes.frames[window[pos]].pose = new[k].clone()
                else:
                    refined = new[k].clone()
    return MapResult(refined, frame_ids, last, True, skipped)
