"""ESLAM's five losses (docs/slam.md, "The pipeline (as implemented)", Losses): three SDF regions, depth and colour,
with named weights.

For a sample at depth ``z`` on a ray with measured depth ``D`` and predicted normalised SDF ``s`` (tanh output):

* free space, ``z < D - T``: ``(s - 1)^2``;
* centre, ``|z - D| < 0.4 T``: ``(z + s T - D)^2``;
* tail, the remaining ``|z - D| <= T``: same form as the centre;
* behind, ``z > D + T``: no loss.

Each SDF term is the mean over all qualifying points pooled across the batch (ESLAM's code, not per-ray means).
``L_d`` is the mean squared depth error over rays, ``L_c`` the mean squared colour error over rays and channels.

The terms are named functions in :data:`LOSS_TERMS` (registered with :func:`loss_term`), and :class:`LossWeights`
holds one weight per term under the same name: :func:`total_loss` sums ``weight * term`` over the registry in its
order. Adding a term: a function ``f(batch: LossBatch) -> scalar tensor`` decorated with ``@loss_term("name")``
below, and a field ``name: float`` in :class:`LossWeights` with its one line of meaning as ``metadata={"doc": ...}``
(config keys ``tracking.weights.name`` / ``mapping.weights.name`` follow from it; docs/configuration.md prints
the line).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import torch

from slam.core import fused_render


@dataclass
class LossWeights:
    """One weight per term of :data:`LOSS_TERMS`, in its order: free space, centre, tail, depth, colour (ESLAM's
    values for tracking and mapping: ``slam.config.TRACKING_WEIGHTS`` / ``MAPPING_WEIGHTS``, the config keys
    ``tracking.weights`` / ``mapping.weights``)."""

    fs: float = field(metadata={"doc": "weight of the free-space term, `(s - 1)^2` of the samples in front of the "
                                       "band, `z < D - T`"})
    center: float = field(metadata={"doc": "weight of the SDF centre term, `(z + s T - D)^2` of the samples within "
                                           "`0.4 T` of the depth"})
    tail: float = field(metadata={"doc": "weight of the SDF tail term, the same of the rest of the band (within `T`)"})
    depth: float = field(metadata={"doc": "weight of the depth term, the mean squared error of the rendered depth"})
    color: float = field(metadata={"doc": "weight of the colour term, the mean squared error of the rendered colour"})


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    # an empty region gives 0 (a sum of nothing over a count clamped to 1), with no host round trip to check it
    return (values * mask).sum() / mask.sum().clamp(min=1)


def sdf_regions(z: torch.Tensor, depth: torch.Tensor, truncation: float):
    """``(front, center, tail)`` ``[R, N]`` bool masks of the samples ``z`` ``[R, N]`` on rays of measured depth
    ``depth`` ``[R]`` (metres): free space ``z < D - T``, the centre ``|z - D| < 0.4 T``, the rest of the band
    ``|z - D| <= T``."""
    D = depth[:, None]
    center = (z - D).abs() < 0.4 * truncation
    return z < D - truncation, center, ((z - D).abs() <= truncation) & ~center


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
    front, center, tail = sdf_regions(z, depth, truncation)
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


@dataclass
class LossBatch:
    """What the terms read: the SDF and depth terms the rays with depth (``sdf``, ``z`` ``[R, N]``; ``depth``,
    ``rendered_depth`` ``[R]``), the colour term every ray (``rendered_color``, ``color`` ``[R', 3]``)."""

    sdf: torch.Tensor
    z: torch.Tensor
    depth: torch.Tensor
    rendered_depth: torch.Tensor
    rendered_color: torch.Tensor
    color: torch.Tensor
    truncation: float

    @cached_property
    def sdf_terms(self) -> dict[str, torch.Tensor]:
        """:func:`sdf_losses` of the batch, computed once for the three SDF terms."""
        return sdf_losses(self.sdf, self.z, self.depth, self.truncation)


#: the terms the fused kernel computes, in its order (:func:`total_loss` uses it while these are all the terms)
FUSED_TERMS = ("fs", "center", "tail", "depth", "color")

#: name -> term, in the order :func:`total_loss` sums them; each name is a field of :class:`LossWeights`
LOSS_TERMS: dict[str, Callable[[LossBatch], torch.Tensor]] = {}


def loss_term(name: str):
    """Decorator: register ``f(batch: LossBatch) -> scalar tensor`` as the loss term ``name`` (after the others)."""

    def register(fn):
        if name in LOSS_TERMS:
            raise ValueError(f"loss term {name!r} is registered twice")
        LOSS_TERMS[name] = fn
        return fn

    return register


@loss_term("fs")
def free_space_term(batch: LossBatch) -> torch.Tensor:
    return batch.sdf_terms["fs"]


@loss_term("center")
def center_term(batch: LossBatch) -> torch.Tensor:
    return batch.sdf_terms["center"]


@loss_term("tail")
def tail_term(batch: LossBatch) -> torch.Tensor:
    return batch.sdf_terms["tail"]


@loss_term("depth")
def depth_term(batch: LossBatch) -> torch.Tensor:
    return depth_loss(batch.rendered_depth, batch.depth)


@loss_term("color")
def color_term(batch: LossBatch) -> torch.Tensor:
    return color_loss(batch.rendered_color, batch.color)


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
    rows: torch.Tensor | None = None,
    fused: bool = False,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted sum of the terms of :data:`LOSS_TERMS`, in its order (``weights`` has one weight per term).

    Args:
        sdf, z: ``[R, N]``.
        rendered_depth, depth: ``[R]``; rendered_color, color: ``[R, 3]``.
        depth_mask: ``[R]`` bool, rays used by the SDF and depth terms (default ``depth > 0``); the colour term
            uses every ray passed in.
        rows: ``[R]`` bool, the rays to use at all (default: every ray): the same as passing ``x[rows]`` of
            every argument, without the copies.
        fused: the five built-in terms in one kernel (:func:`slam.core.fused_render.loss_terms`) where it can run
            (CPU, float, no other term registered), the same values to a few ulp; otherwise PyTorch ops.

    Returns:
        ``(loss, parts)`` with the scalar loss and the unweighted terms as detached 0-d tensors. A term whose
        weight is 0 is still computed and added as ``0 * term`` (so a NaN term still makes the loss NaN).
    """
    if depth_mask is None:
        depth_mask = depth > 0
    if fused and tuple(LOSS_TERMS) == FUSED_TERMS and fused_render.eligible(
            sdf, rendered_depth, rendered_color, constant=(z, depth, color)):
        terms = fused_render.loss_terms(sdf, z, rendered_depth, rendered_color, depth, color, truncation, depth_mask,
                                        rows)
        parts = dict(zip(FUSED_TERMS, terms.unbind()))
    else:
        if rows is not None:
            sdf, z, rendered_depth, rendered_color = sdf[rows], z[rows], rendered_depth[rows], rendered_color[rows]
            depth, color, depth_mask = depth[rows], color[rows], depth_mask[rows]
        batch = LossBatch(sdf[depth_mask], z[depth_mask], depth[depth_mask], rendered_depth[depth_mask],
                          rendered_color, color, truncation)
        parts = {name: term(batch) for name, term in LOSS_TERMS.items()}
    loss = None
    for name, part in parts.items():  # left to right, as ``w1 * t1 + w2 * t2 + ...``: the same rounding
        weighted = getattr(weights, name) * part
        loss = weighted if loss is None else loss + weighted
    # the parts stay tensors: converting them to floats would wait on the device every iteration, for a log line
    return loss, {k: v.detach() for k, v in parts.items()}
