"""Functional core: world points to grid coordinates, and multilinear interpolation of channels-last grids.

These are the pure-PyTorch references every kind uses, through :mod:`tdfields.ops`, which runs the fused kernels
where they apply (this module imports neither). Interpolation gathers ``2**d`` corner rows from a
``[*spatial, F]`` tensor viewed as ``[prod(spatial), F]``: measured on a 2-core CPU it beats ``grid_sample`` for
planes (160 ms vs 212 ms forward+backward, 40k points, three 32-channel planes), and it is built from ordinary
differentiable ops, so second derivatives (eikonal terms, normals) and ``torch.compile`` work, and gradients flow
to the query coordinates (SLAM tracking needs them).
"""

from __future__ import annotations

import itertools
from typing import Sequence

import torch


def to_grid_coords(points: torch.Tensor, aabb: torch.Tensor, shape: Sequence[int]) -> torch.Tensor:
    """Map world points to continuous grid indices, clamped to the border.

    Sample ``0`` sits on the box's lower face and sample ``n - 1`` on its upper face (``align_corners=True``
    in ``grid_sample`` terms, as ESLAM uses). Points outside the box are clamped to the border, so their
    features are the border features and their coordinate gradient is zero.

    Args:
        points: ``[..., 3]`` world coordinates in metres (differentiable).
        aabb: ``(3, 2)`` box in metres.
        shape: ``(n_x, n_y, n_z)`` samples per axis.

    Returns:
        ``[..., 3]`` grid coordinates in ``[0, n_a - 1]`` (float, differentiable).
    """
    box = aabb.to(device=points.device, dtype=points.dtype)
    n = torch.as_tensor(shape, device=points.device, dtype=points.dtype)
    g = (points - box[:, 0]) / (box[:, 1] - box[:, 0]) * (n - 1)
    return torch.minimum(torch.maximum(g, torch.zeros_like(n)), n - 1)


def interpolate_reference(grid: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Multilinear interpolation of a channels-last grid at continuous indices: the pure-PyTorch reference.

    Args:
        grid: ``[s_0, ..., s_{d-1}, F]`` values at integer sample positions (each ``s_i >= 2``).
        coords: ``[N, d]`` continuous indices, already clamped to ``[0, s_i - 1]``.

    Returns:
        ``[N, F]`` interpolated values; differentiable w.r.t. ``grid`` and ``coords`` (to any order).
    """
    d = coords.shape[-1]
    sizes = grid.shape[:d]
    if grid.dim() != d + 1:
        raise ValueError(f"grid must have {d} spatial dims plus channels, got shape {tuple(grid.shape)}")
    flat = grid.reshape(-1, grid.shape[-1])
    # the lower corner is at most s-2 so that the upper corner s-1 exists; the weight then reaches 1 at the edge
    lower = []
    weight = []
    for axis in range(d):
        c = coords[:, axis]
        i0 = c.detach().floor().clamp(0, sizes[axis] - 2)
        lower.append(i0.long())
        weight.append((c - i0).unsqueeze(-1))
    strides = [1] * d
    for axis in range(d - 2, -1, -1):
        strides[axis] = strides[axis + 1] * sizes[axis + 1]
    base = sum(lower[a] * strides[a] for a in range(d))
    out = None
    # 2**d corners (at most 8): a loop over corners, never over ranks, factors or points
    for corner in itertools.product((0, 1), repeat=d):
        offset = sum(strides[a] for a in range(d) if corner[a])
        w = None
        for a in range(d):
            wa = weight[a] if corner[a] else 1 - weight[a]
            w = wa if w is None else w * wa
        term = flat[base + offset] * w
        out = term if out is None else out + term
    return out
