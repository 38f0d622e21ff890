"""Deferred colour for the TensoRF-style models: the colour head runs once per ray on the ray's composited
appearance features, instead of once per sample (``--pipeline.model.colour-head deferred``).

TensoRF colours every fine sample with its MLP and composites the colours: ``C = sum_i w_i h(B f_i, d) + (1 - A) bg``.
Deferred shading (as in SNeRG, Hedman et al. 2021) composites the features first and decodes once:
``C = A h(B f_bar, d) + (1 - A) bg`` with ``f_bar = sum_i w_i f_i / A`` the weighted mean of the ray's features, the
same modules (``B``, the frequency encodings, the MLP, the sigmoid output), weights ``w_i`` and accumulation ``A``.
``B`` is linear, so it is applied after the sum.
The head's work drops from rays x samples to rays: in nerfstudio's TensoRF the head alone is a third of a training
step (docs/nerf.md, "Where a step's time goes"). It is exact for colour that does not vary along the ray's visible
samples (an opaque first surface: the mean is that feature, so the colour is the per-sample one) and an
approximation otherwise; docs/nerf.md measures what it costs in PSNR.
"""

from __future__ import annotations

from typing import Dict

import torch

# first: without nerfstudio its ImportError names the extra to install
import tdfields.integrations.nerfstudio  # noqa: F401  isort: skip

from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import SceneBox


def _scatter(mask: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """``values [M, ...]`` of the rays where ``mask [R]`` holds, as ``[R, ...]`` with zeros elsewhere
    (differentiable); ``values`` itself when every ray is in the mask."""
    if values.shape[0] == mask.shape[0]:
        return values
    out = values.new_zeros((mask.shape[0], *values.shape[1:]))
    return out.index_put((mask,), values)


def ray_colour(field, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """TensoRF's colour head at composited features: ``features [R, F]`` (the colour encoding's channels, summed
    with the rendering weights), unit ``directions [R, 3]`` -> ``[R, 3]`` colours in [0, 1]."""
    feats = field.B(features)
    head_in = torch.cat([feats, directions, field.feature_encoding(feats), field.direction_encoding(directions)], -1)
    return field.field_output_rgb(field.mlp_head(head_in))


def deferred_outputs(model, ray_bundle: RayBundle) -> Dict[str, torch.Tensor]:
    """``TensoRFModel.get_outputs`` with the colour head run per ray (module doc): the same samplers, density,
    weights, accumulation, depth and background blending; ``{"rgb": [R, 3], "accumulation": [R, 1], "depth": [R, 1]}``.
    """
    field = model.field
    if model.training:
        model.camera_optimizer.apply_to_raybundle(ray_bundle)
    uniform = model.sampler_uniform(ray_bundle)
    weights = uniform.get_weights(field.get_density(uniform))
    # as TensoRF: rays the coarse pass sees as empty get no fine field query (zero density, background colour)
    live = (model.renderer_accumulation(weights) >= 1e-4).reshape(-1)
    pdf = model.sampler_pdf(ray_bundle, uniform, weights)

    n_rays, n_samples = pdf.shape
    if bool(live.any()):
        samples = pdf if bool(live.all()) else pdf[live]
        positions = SceneBox.get_normalized_positions(samples.frustums.get_positions(), field.aabb) * 2 - 1
        density = _scatter(live, field.get_density(samples))
        features = _scatter(live, field.color_encoding(positions))
    else:
        density = weights.new_zeros((n_rays, n_samples, 1))
        features = weights.new_zeros((n_rays, n_samples, field.color_encoding.get_out_dim()))
    weights_fine = pdf.get_weights(density)
    accumulation = model.renderer_accumulation(weights_fine)
    depth = model.renderer_depth(weights_fine, pdf)
    mean = (weights_fine * features).sum(-2) / accumulation.clamp(min=1e-6)
    colour = ray_colour(field, mean, ray_bundle.directions)
    # one colour per ray, composited by the renderer as if every sample had it: A * colour + (1 - A) * background
    rgb = model.renderer_rgb(rgb=colour[:, None, :].expand(-1, n_samples, -1), weights=weights_fine)
    return {"rgb": rgb, "accumulation": accumulation.clamp(min=0), "depth": depth}
