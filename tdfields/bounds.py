"""Scene boxes and grid resolutions.

All arithmetic here is float32 on purpose: ESLAM computes its enlarged bound and the per-axis sample counts
on a float32 CPU tensor, and the published parameter counts (LRSLAM Table 1) depend on that rounding
(room0's y extent 6.72 becomes 6.7199995, so 6.72/0.24 gives 27 samples, not 28).
"""

from __future__ import annotations

from typing import Sequence

import torch

AabbLike = "torch.Tensor | Sequence[Sequence[float]]"


def as_aabb(aabb, name: str = "aabb") -> torch.Tensor:
    """Validate and convert a box to a float32 tensor.

    Args:
        aabb: ``[[x0, x1], [y0, y1], [z0, z1]]`` in metres (nested sequence or tensor of shape ``(3, 2)``).
        name: how to call the argument in error messages.

    Returns:
        ``(3, 2)`` float32 tensor on the CPU (or on the input tensor's device).

    Raises:
        ValueError: wrong shape, non-finite values, or an empty/inverted interval, naming the axis.
    """
    t = torch.as_tensor(aabb, dtype=torch.float32)
    if t.shape != (3, 2):
        raise ValueError(f"{name} must have shape (3, 2) as [[x0, x1], [y0, y1], [z0, z1]], got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name} contains NaN or inf: {t.tolist()}")
    for axis, label in enumerate("xyz"):
        if not t[axis, 1] > t[axis, 0]:
            raise ValueError(f"{name}: {label} interval must have x1 > x0, got {t[axis].tolist()}")
    return t


def enlarge_bounds(aabb, multiple: float = 0.24) -> torch.Tensor:
    """ESLAM's one-off bound enlargement: ``b_max <- b_min + (floor((b_max - b_min) / m) + 1) * m``.

    The result always grows by up to one extra ``multiple`` per axis, so every coarse cell size that divides
    ``multiple`` tiles the box. Computed in float32 to reproduce the reference implementation bit for bit.

    Args:
        aabb: ``[[x0, x1], [y0, y1], [z0, z1]]`` in metres.
        multiple: the divisor in metres (ESLAM: ``planes_res.bound_dividable`` = 0.24).

    Returns:
        ``(3, 2)`` float32 tensor, metres.
    """
    if not multiple > 0:
        raise ValueError(f"multiple must be positive, got {multiple}")
    box = as_aabb(aabb)
    m = torch.tensor(multiple, dtype=torch.float32)
    extent = box[:, 1] - box[:, 0]
    out = box.clone()
    out[:, 1] = box[:, 0] + (torch.floor(extent / m) + 1) * m
    return out


def grid_shape_for(aabb, cell_size: float | Sequence[float]) -> tuple[int, int, int]:
    """Samples per axis for a cell size: ``n_a = floor(extent_a / cell_size)`` in float32 (ESLAM's rule).

    Args:
        aabb: ``(3, 2)`` box in metres.
        cell_size: metres, one value or one per axis.

    Returns:
        ``(n_x, n_y, n_z)``; each at least 2 so that linear interpolation is defined.
    """
    box = as_aabb(aabb)
    cell = torch.as_tensor(cell_size, dtype=torch.float32).expand(3)
    if not (cell > 0).all():
        raise ValueError(f"cell_size must be positive, got {cell_size}")
    n = torch.floor((box[:, 1] - box[:, 0]) / cell).long().clamp(min=2)
    return tuple(int(v) for v in n.tolist())  # type: ignore[return-value]


def contains(aabb: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Which points lie inside the closed box.

    Args:
        aabb: ``(3, 2)`` box in metres.
        points: ``[..., 3]`` world coordinates in metres.

    Returns:
        ``[...]`` bool mask (not differentiable).
    """
    box = aabb.to(points.device, points.dtype)
    return ((points >= box[:, 0]) & (points <= box[:, 1])).all(dim=-1)
