"""ESLAM's five losses (docs/slam.md, "The pipeline (as implemented)", Losses): three SDF regions, depth and colour,
with named weights.

For a sample at depth ``z`` on a ray with measured depth ``D`` and predicted normalised SDF ``s`` (tanh output):

* free space, ``z < D - T``: ``(s - 1)^2``;
* centre, ``|z - D| < 0.4 T``: ``(z + s T - D)^2``;
* tail, the remaining ``|z - D| <= T``: same form as the centre;
* behind, ``z > D + T``: no loss.

Each SDF term is the mean over all qualifying points pooled across the batch (ESLAM's code, not per-ray means).
``L_d`` is the mean squared depth error over rays, ``L_c`` the mean squared colour error over rays and channels.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class LossWeights:
    """Weights of the five terms: free space, centre, tail, depth, colour (ESLAM's values for tracking and mapping:
    ``slam.config.TRACKING_WEIGHTS`` / ``MAPPING_WEIGHTS``, the config keys ``tracking.weights`` / ``mapping.weights``)."""

    fs: float
    center: float
    tail: float
    depth: float
    color: float


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    # an empty region gives 0 (a sum of nothing over a count clamped to 1), with no host round trip to check it
    return (values * mask).sum() / mask.sum().clamp(min=1)


def sdf_losses(sdf: torch.Tensor, z: torch.Tensor, depth: torch.Tensor, truncation: float) -> dict[str, torch.Tensor]:
    """The three SDF terms.

    Args:
        sdf: ``[R, N]`` normalised SDF at the samples.
        z: ``[R, N]`` sample depths (metres).
        depth: ``[R]`` measured depth (metres); call with rays that have ``D > 0`` only.
        truncation: ``T`` in metres.

    Returns:
        ``{"fs", "center", "tail"}`` scalar tensors (0 when a region is empty).
    """
    D = depth[:, None]
    front = z < D - truncation
    center = (z - D).abs() < 0.4 * truncation
    band = (z - D).abs() <= truncation
    tail = band & ~center
    sdf_err = (z + sdf * truncation - D) ** 2
    return {
        "fs": _masked_mean((sdf - 1.0) ** 2, front),
        "center": _masked_mean(sdf_err, center),
        "tail": _masked_mean(sdf_err, tail),
    }


def depth_loss(rendered: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """Mean squared depth error over rays (``[R]`` each)."""
    if rendered.numel() == 0:
        return rendered.sum() * 0.0
    return ((rendered - depth) ** 2).mean()


def color_loss(rendered: torch.Tensor, color: torch.Tensor) -> torch.Tensor:
    """Mean squared colour error over rays and channels (``[R, 3]`` each, RGB in [0, 1])."""
    if rendered.numel() == 0:
        return rendered.sum() * 0.0
    return ((rendered - color) ** 2).mean()


def tracking_inliers(rendered_depth: torch.Tensor, depth: torch.Tensor, factor: float = 10.0) -> torch.Tensor:
    """ESLAM tracking outlier rule: keep rays with ``|D - d_hat| < factor * median(|D - d_hat|)`` (``[R]`` bool)."""
    err = (depth - rendered_depth.detach()).abs()
    if err.numel() == 0:
        return err > 0
    return err < factor * err.median()


def total_loss(
    sdf: torch.Tensor,
    z: torch.Tensor,
    rendered_depth: torch.Tensor,
    rendered_color: torch.Tensor,
    depth: torch.Tensor,
    color: torch.Tensor,
    truncation: float,
    weights: LossWeights,
    depth_mask: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted sum of the five terms.

    Args:
        sdf, z: ``[R, N]``.
        rendered_depth, depth: ``[R]``; rendered_color, color: ``[R, 3]``.
        depth_mask: ``[R]`` bool, rays used by the SDF and depth terms (default ``depth > 0``); the colour term
            uses every ray passed in.

    Returns:
        ``(loss, parts)`` with the scalar loss and the unweighted terms as detached 0-d tensors.
    """
    if depth_mask is None:
        depth_mask = depth > 0
    parts = sdf_losses(sdf[depth_mask], z[depth_mask], depth[depth_mask], truncation)
    parts["depth"] = depth_loss(rendered_depth[depth_mask], depth[depth_mask])
    parts["color"] = color_loss(rendered_color, color)
    loss = (
        weights.fs * parts["fs"]
        + weights.center * parts["center"]
        + weights.tail * parts["tail"]
        + weights.depth * parts["depth"]
        + weights.color * parts["color"]
    )
    # the parts stay tensors: converting them to floats would wait on the device every iteration, for a log line
    return loss, {k: v.detach() for k, v in parts.items()}
