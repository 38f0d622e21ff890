"""Functional ray core: pixel rays, ray/box exit, where rays are sampled, and ESLAM's SDF volume compositing (the
sample depths themselves: :mod:`slam.core.sampling`).

Nothing here owns a model. :func:`render_rays` takes two callables, ``sdf_fn(points) -> sdf`` and
``rgb_fn(points) -> rgb``, so the same code renders any representation (and a hand-written stand-in in the tests).

Conventions (see docs/data.md): OpenCV camera, x right, y down, z forward. The pixel direction is
``d = ((u - cx)/fx, (v - cy)/fy, 1)`` rotated into the world and **not normalised**, so the ray parameter ``z`` is
the camera-axis depth and compares directly with the sensor depth ``D``. Lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from slam.core import fused_render
from slam.core.camera import pixel_directions
from slam.core.sampling import perturb_depths, sample_depth_rays, sample_pdf

SdfFn = Callable[[torch.Tensor], torch.Tensor]
RgbFn = Callable[[torch.Tensor], torch.Tensor]


def camera_rays(c2w: torch.Tensor, dirs_cam: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World rays for camera-frame directions.

    Args:
        c2w: ``[4, 4]`` or ``[R, 4, 4]`` camera-to-world (differentiable: tracking optimises it).
        dirs_cam: ``[R, 3]`` camera-frame directions (z = 1).

    Returns:
        ``(origins [R, 3], dirs [R, 3])`` in world metres; ``dirs`` keep unit camera-z.
    """
    if c2w.dim() == 2:
        dirs = dirs_cam @ c2w[:3, :3].T
        origins = c2w[:3, 3].expand_as(dirs)
    else:
        dirs = (c2w[:, :3, :3] @ dirs_cam[..., None])[..., 0]
        origins = c2w[:, :3, 3]
    return origins, dirs


def ray_box_exit(origins: torch.Tensor, dirs: torch.Tensor, aabb: torch.Tensor) -> torch.Tensor:
    """Ray parameter at which each ray leaves the box (slab test; not differentiable).

    Args:
        origins, dirs: ``[R, 3]``.
        aabb: ``(3, 2)`` box in metres.

    Returns:
        ``[R]`` exit distance in units of the ray parameter (camera depth); ``<= 0`` means the box is behind.
    """
    o = origins.detach()
    d = dirs.detach()
    box = aabb.to(o)
    d = torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)
    t0 = (box[:, 0] - o) / d
    t1 = (box[:, 1] - o) / d
    return torch.maximum(t0, t1).min(-1).values


def sdf_to_alpha(sdf: torch.Tensor, beta: torch.Tensor | float) -> torch.Tensor:
    """StyleSDF density and ESLAM opacity: ``alpha = 1 - exp(-beta * sigmoid(-beta * s))`` (no interval length)."""
    sigma = beta * torch.sigmoid(-beta * sdf)
    return 1.0 - torch.exp(-sigma)


def composite_weights(alpha: torch.Tensor) -> torch.Tensor:
    """``w_n = alpha_n * prod_{k<n} (1 - alpha_k + 1e-10)`` along the last axis (``[R, N]``)."""
    trans = torch.cumprod(1.0 - alpha + 1e-10, -1)
    trans = torch.cat((torch.ones_like(trans[..., :1]), trans[..., :-1]), -1)
    return alpha * trans


def composite(sdf: torch.Tensor, beta: torch.Tensor | float, z: torch.Tensor,
              fused: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """``(weights [R, N], depth [R])`` of SDF samples ``sdf [R, N]`` at depths ``z [R, N]`` (metres): ESLAM's
    compositing, with the fused kernel (:func:`slam.core.fused_render.composite`; check
    :func:`slam.core.fused_render.eligible` first) or these PyTorch ops."""
    if fused:
        return fused_render.composite(sdf, beta, z)
    w = composite_weights(sdf_to_alpha(sdf, beta))
    return w, (w * z).sum(-1)


def color_sum(weights: torch.Tensor, rgb: torch.Tensor, fused: bool = False) -> torch.Tensor:
    """``[R, 3]`` rendered colour ``sum_n w_n rgb_n`` of weights ``[R, N]`` and sample colours ``[R, N, 3]``, fused
    (:func:`slam.core.fused_render.color_sum`) or not, as :func:`composite` was."""
    return fused_render.color_sum(weights, rgb) if fused else (weights[..., None] * rgb).sum(-2)


@dataclass
class RenderOut:
    """Per-ray rendering: ``depth [R]``, ``color [R, 3]``, raw ``sdf [R, N]`` and sample depths ``z [R, N]``."""

    depth: torch.Tensor
    color: torch.Tensor
    sdf: torch.Tensor
    z: torch.Tensor
    weights: torch.Tensor


def render_rays(
    origins: torch.Tensor,
    dirs: torch.Tensor,
    depth: torch.Tensor,
    sdf_fn: SdfFn,
    rgb_fn: RgbFn,
    beta: torch.Tensor | float,
    truncation: float,
    n_stratified: int,
    n_importance: int,
    aabb: torch.Tensor | None = None,
    perturb: bool = True,
    generator: torch.Generator | None = None,
    color_cutoff: float = 0.0,
    fused: bool = False,
) -> RenderOut:
    """Render rays with ESLAM's sampling and compositing.

    Rays with ``depth > 0`` sample around the measurement; rays without depth (``depth <= 0``) sample
    ``[0, t_exit + 0.01]`` stratified, then ``n_importance`` inverse-CDF samples from a no-grad SDF pass.

    Args:
        origins, dirs: ``[R, 3]`` world rays (``dirs`` with unit camera z; differentiable for tracking/BA).
        depth: ``[R]`` measured depth in metres, ``0`` where invalid.
        sdf_fn: ``points [P, 3] -> sdf [P]``, normalised (tanh).
        rgb_fn: ``points [P, 3] -> rgb [P, 3]`` in (0, 1).
        beta: sharpness of the SDF-to-density map (scalar tensor or float).
        truncation: TSDF truncation ``T`` in metres.
        aabb: ``(3, 2)`` scene box, required when some rays have no depth.
        color_cutoff: samples whose compositing weight is at most this get no colour query (their colour counts
            as 0). ``0`` queries every sample, as ESLAM does. A positive cutoff skips the free space in front of a
            surface and everything behind it, so the rendered colour changes by at most ``N * color_cutoff``.
        fused: composite with the fused kernel (:mod:`slam.core.fused_render`) where it can run (CPU, float),
            the same values to a few ulp and the same gradients; otherwise this module's PyTorch ops.

    Returns:
        :class:`RenderOut`.
    """
    R = depth.shape[0]
    N = n_stratified + n_importance
    z = _sample_ray_depths(origins, dirs, depth, sdf_fn, beta, truncation, n_stratified, n_importance, aabb, perturb,
                           generator)
    pts = (origins[:, None, :] + dirs[:, None, :] * z[..., None]).reshape(-1, 3)
    sdf = sdf_fn(pts).reshape(R, N)
    fused = fused and fused_render.eligible(sdf, constant=(z,))
    w, depth_hat = composite(sdf, beta, z, fused)
    rgb = sample_colors(pts, w, rgb_fn, color_cutoff)
    return RenderOut(depth=depth_hat, color=color_sum(w, rgb, fused), sdf=sdf, z=z, weights=w)


def _sample_ray_depths(origins, dirs, depth, sdf_fn: SdfFn, beta, truncation: float, n_stratified: int,
                       n_importance: int, aabb, perturb: bool, generator) -> torch.Tensor:
    """``[R, n_stratified + n_importance]`` sample depths of :func:`render_rays`: around the measurement where
    ``depth > 0``, :func:`_sample_free_rays` elsewhere."""
    valid = depth > 0
    if bool(valid.all()):
        return sample_depth_rays(depth, n_stratified, n_importance, truncation, perturb, generator)
    z = torch.empty((depth.shape[0], n_stratified + n_importance), dtype=origins.dtype, device=origins.device)
    if bool(valid.any()):
        z[valid] = sample_depth_rays(depth[valid], n_stratified, n_importance, truncation, perturb, generator)
    inv = ~valid
    if aabb is None:
        raise ValueError("rays without depth need the scene aabb")
    z[inv] = _sample_free_rays(origins[inv], dirs[inv], sdf_fn, beta, n_stratified, n_importance, aabb, perturb,
                               generator)
    return z


def sample_colors(pts: torch.Tensor, w: torch.Tensor, rgb_fn: RgbFn, color_cutoff: float) -> torch.Tensor:
    """``[R, N, 3]`` colours of the samples ``pts`` ``[R * N, 3]``; with ``color_cutoff > 0`` only samples whose
    weight ``w`` ``[R, N]`` exceeds it are queried (the others are 0)."""
    R, N = w.shape
    if color_cutoff <= 0:
        return rgb_fn(pts).reshape(R, N, 3)
    keep = (w.detach() > color_cutoff).reshape(-1)
    rgb = pts.new_zeros(R * N, 3)
    rgb[keep] = rgb_fn(pts[keep])
    return rgb.reshape(R, N, 3)


def _sample_free_rays(origins, dirs, sdf_fn: SdfFn, beta, n_stratified: int, n_importance: int, aabb, perturb: bool,
                      generator) -> torch.Tensor:
    """Sample depths ``[R, n_stratified + n_importance]`` of rays without a depth reading: stratified over
    ``[0, t_exit + 0.01]``, then importance samples from a no-grad SDF pass."""
    far = ray_box_exit(origins, dirs, aabb).clamp(min=0.0) + 0.01
    lin = torch.linspace(0.0, 1.0, n_stratified, dtype=origins.dtype, device=origins.device)
    zs = far[:, None] * lin
    if perturb:
        zs = perturb_depths(zs, generator)
    if n_importance > 0:
        with torch.no_grad():
            pts = origins.detach()[:, None] + dirs.detach()[:, None] * zs[..., None]
            s = sdf_fn(pts.reshape(-1, 3))
            w = composite_weights(sdf_to_alpha(s.reshape(zs.shape), beta))
            mids = 0.5 * (zs[..., 1:] + zs[..., :-1])
            zi = sample_pdf(mids, w[..., 1:-1], n_importance, generator, deterministic=not perturb)
        zs = torch.sort(torch.cat((zs, zi), -1), -1).values
    return zs


def render_pixels(scene, *, u: torch.Tensor, v: torch.Tensor, depth: torch.Tensor, color: torch.Tensor,
                  c2w: torch.Tensor, intrinsics, rendering, truncation: float, perturb: bool,
                  generator: torch.Generator | None, depth_required: bool, min_rays: int = 1):
    """From pixels to a render: the one path the tracker and the mapper share.

    Rays through pixels ``(u, v)`` of cameras ``c2w`` are kept where the measured surface lies inside the scene
    box (and, with ``depth_required``, where there is a depth reading), then rendered with :func:`render_rays`.

    Args:
        scene: anything with ``sdf``, ``rgb``, ``beta`` and ``aabb`` (``[3, 2]`` metres), e.g.
            :class:`slam.model.scene.SceneModel`.
        u, v: ``[R]`` pixel columns and rows (integer or float).
        depth: ``[R]`` measured depth at the pixels in metres (0 = none); color: ``[R, 3]`` RGB in [0, 1].
        c2w: ``[4, 4]`` camera-to-world, or ``[R, 4, 4]`` one per ray (differentiable: tracking and BA go
            through it).
        intrinsics: ``fx, fy, cx, cy`` of the working image (pixels).
        rendering: the ``rendering`` config (``n_stratified``, ``n_importance``, ``color_cutoff``, ``fused``).
        truncation: TSDF truncation in metres.
        min_rays: fewer kept rays than this returns None.

    Returns:
        ``(RenderOut, depth [R'], color [R', 3])`` of the ``R'`` kept rays, or None.
    """
    dirs_cam = pixel_directions(u.to(depth.dtype), v.to(depth.dtype), intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                intrinsics.cy)
    origins, dirs = camera_rays(c2w, dirs_cam)
    keep = ray_box_exit(origins, dirs, scene.aabb) >= depth
    if depth_required:
        keep = (depth > 0) & keep
    if int(keep.sum()) < min_rays:
        return None
    origins, dirs, depth, color = origins[keep], dirs[keep], depth[keep], color[keep]
    out = render_rays(origins, dirs, depth, scene.sdf, scene.rgb, scene.beta, truncation, rendering.n_stratified,
                      rendering.n_importance, scene.aabb, perturb, generator, rendering.color_cutoff,
                      rendering.fused)
    return out, depth, color
