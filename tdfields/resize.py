"""Change a field's resolution or box in place, resampling its factors and the optimizer state with them.

TensoRF-style coarse-to-fine training and SLAM with a growing scene box both need this. :func:`resize` resamples
every factor by evaluating its interpolant at the new sample positions in world coordinates, so a change of
resolution and a change of box are the same operation; new samples outside the old box take border values.
:func:`grow` is the exact special case of a box grown by whole samples: the old samples are copied, not resampled.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch

from tdfields.bounds import as_aabb, grid_shape_for
from tdfields.field import Field
from tdfields.interpolation import to_grid_coords
from tdfields.ops import interpolate


def _sample_positions(old_aabb: torch.Tensor, old_shape, new_aabb: torch.Tensor, new_shape, axes) -> torch.Tensor:
    """Old-grid coordinates ``[prod(new sizes), len(axes)]`` of the new grid's samples along ``axes``."""
    lines = []
    for a in axes:
        world = torch.linspace(float(new_aabb[a, 0]), float(new_aabb[a, 1]), new_shape[a], dtype=torch.float64)
        pts = torch.zeros(new_shape[a], 3, dtype=torch.float64)
        pts[:, a] = world
        lines.append(to_grid_coords(pts, old_aabb.double(), old_shape)[:, a])
    mesh = torch.meshgrid(*lines, indexing="ij")
    return torch.stack([m.reshape(-1) for m in mesh], dim=-1)


def _resample(t: torch.Tensor, coords: torch.Tensor, new_sizes: Sequence[int]) -> torch.Tensor:
    out = interpolate(t.detach().double(), coords.to(t.device))
    return out.reshape(*new_sizes, t.shape[-1]).to(t.dtype)


@torch.no_grad()
def resize(field: Field, *, grid_shape: Sequence[int] | None = None, cell_size: float | None = None,
           aabb=None, optimizer: torch.optim.Optimizer | None = None) -> Field:
    """Resample ``field`` to a new grid and/or box, in place, keeping optimizer state consistent.

    Args:
        field: any :class:`tdfields.Field`.
        grid_shape: new ``(n_x, n_y, n_z)``; or
        cell_size: new spacing in metres (``floor(extent / cell)`` samples, float32, as at construction);
            with neither, the grid shape is kept (only the box changes).
        aabb: new ``(3, 2)`` box in metres; default keeps the box.
        optimizer: an optimizer holding the field's factors. Each old factor is swapped for the new one in
            its param group, and per-parameter state tensors with the factor's shape (Adam's moments) are
            resampled the same way; scalar state (``step``) is kept. No need to rebuild the optimizer.

    Returns:
        ``field`` itself, with new ``Parameter`` objects for every factor.
    """
    if grid_shape is not None and cell_size is not None:
        raise ValueError("resize: give grid_shape or cell_size, not both")
    old_aabb = field.aabb.detach().cpu().clone()
    old_shape = field.grid_shape
    new_aabb = old_aabb if aabb is None else as_aabb(aabb)
    if cell_size is not None:
        new_shape = grid_shape_for(new_aabb, cell_size)
    elif grid_shape is not None:
        new_shape = tuple(int(n) for n in grid_shape)
        if len(new_shape) != 3 or min(new_shape) < 2:
            raise ValueError(f"resize: grid_shape must be three sample counts >= 2, got {tuple(grid_shape)}")
    else:
        new_shape = old_shape
    changes = {}
    for name, spec in field.factor_specs().items():
        sizes = [new_shape[a] for a in spec.axes]
        coords = _sample_positions(old_aabb, old_shape, new_aabb, new_shape, spec.axes)
        changes[name] = lambda t, coords=coords, sizes=sizes: _resample(t, coords, sizes)
    _replace_factors(field, changes, optimizer)
    _set_grid(field, new_aabb, new_shape)
    if cell_size is not None:
        field.cell_size = cell_size
    elif grid_shape is not None:
        field.cell_size = None
    return field


def _replace_factors(field: Field, changes: dict, optimizer: torch.optim.Optimizer | None) -> None:
    """Swap every factor ``name`` for ``changes[name](factor)`` (and optimizer state of the factor's shape alike)."""
    swaps: dict[torch.nn.Parameter, torch.nn.Parameter] = {}
    for name, change in changes.items():
        old = field.factors[name]
        new = torch.nn.Parameter(change(old.detach()), requires_grad=old.requires_grad)
        if optimizer is not None and old in optimizer.state:
            state = optimizer.state.pop(old)
            optimizer.state[new] = {k: change(v) if torch.is_tensor(v) and v.shape == old.shape else v
                                    for k, v in state.items()}
        swaps[old] = new
        field.factors[name] = new
    if optimizer is not None:
        for group in optimizer.param_groups:
            group["params"] = [swaps.get(p, p) for p in group["params"]]


def _set_grid(field: Field, aabb: torch.Tensor, shape: tuple[int, int, int]) -> None:
    field.aabb.copy_(aabb.to(field.aabb))
    field.grid_shape = tuple(shape)  # type: ignore[assignment]
    field.clear_cache()
    assert field.num_parameters() == field.closed_form_parameters(), "resize produced inconsistent factors"
    assert all(math.prod(p.shape) == p.numel() for p in field.parameters())


def pad_factor(t: torch.Tensor, axes: Sequence[int], lower: Sequence[int], upper: Sequence[int]) -> torch.Tensor:
    """A channels-last factor ``[*sizes, F]`` spanning ``axes`` with ``lower[a]`` / ``upper[a]`` samples added below /
    above along each axis ``a`` it spans, each a copy of the border sample (the old samples are copied exactly)."""
    for dim, a in enumerate(axes):
        lo, hi = int(lower[a]), int(upper[a])
        if lo or hi:
            first = t.narrow(dim, 0, 1).expand(*t.shape[:dim], lo, *t.shape[dim + 1:])
            last = t.narrow(dim, t.shape[dim] - 1, 1).expand(*t.shape[:dim], hi, *t.shape[dim + 1:])
            t = torch.cat([first, t, last], dim=dim)
    return t.contiguous()


def grown_aabb(aabb: torch.Tensor, shape: Sequence[int], lower: Sequence[int], upper: Sequence[int]) -> torch.Tensor:
    """The ``(3, 2)`` box (``aabb``'s dtype) of a grid ``shape`` over ``aabb`` grown by whole samples: ``lower[a]`` /
    ``upper[a]`` sample spacings (``extent / (n - 1)``, in float64) below / above on axis ``a``."""
    box = aabb.detach().cpu().double()
    step = (box[:, 1] - box[:, 0]) / (torch.as_tensor(shape, dtype=torch.float64) - 1)
    out = torch.stack([box[:, 0] - step * torch.as_tensor(lower, dtype=torch.float64),
                       box[:, 1] + step * torch.as_tensor(upper, dtype=torch.float64)], dim=-1)
    return out.to(aabb.dtype)


@torch.no_grad()
def grow(field: Field, lower: Sequence[int], upper: Sequence[int],
         optimizer: torch.optim.Optimizer | None = None) -> Field:
    """Grow ``field``'s box by whole samples, in place: ``lower[a]`` / ``upper[a]`` samples below / above on axis
    ``a`` (each ``>= 0``), the sample spacing unchanged.

    Unlike :func:`resize`, nothing is resampled: the old samples are copied bit for bit and the new ones are copies
    of the border samples, so the field is the same function as before wherever it was queried, outside the old box
    too (a query there read the border before, clamped, and reads the same values now), up to the float32
    rounding of the new box. Optimizer state of a factor's shape (Adam's moments) is padded the same way.

    Returns:
        ``field`` itself, with new ``Parameter`` objects for every factor.
    """
    lower, upper = [int(v) for v in lower], [int(v) for v in upper]
    if len(lower) != 3 or len(upper) != 3 or min(lower + upper) < 0:
        raise ValueError(f"grow: lower and upper must be three sample counts >= 0, got {lower}, {upper}")
    new_aabb = grown_aabb(field.aabb, field.grid_shape, lower, upper)
    new_shape = tuple(n + lo + hi for n, lo, hi in zip(field.grid_shape, lower, upper))
    changes = {name: lambda t, axes=spec.axes: pad_factor(t, axes, lower, upper)
               for name, spec in field.factor_specs().items()}
    _replace_factors(field, changes, optimizer)
    _set_grid(field, new_aabb, new_shape)
    field.cell_size = None
    return field
