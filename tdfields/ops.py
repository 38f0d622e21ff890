"""The operations every field is made of, each run by a fused kernel where one applies and by the pure-PyTorch
reference otherwise: world points to grid coordinates, interpolation, the evaluation of a factor
:class:`~tdfields.program.Program`, and the composition of a rank-k plane from two line factors.

Fields call these and nothing below them, so a field never knows which backend runs it. The choice is made per
call by :func:`tdfields.kernels.use_triton` / :func:`tdfields.kernels.use_fused` (device, dtype, backend setting,
``torch.compile`` tracing); the fused paths are first-order only, the references differentiable to any order.
"""

from __future__ import annotations

from typing import Sequence

import torch

from tdfields import kernels
from tdfields.interpolation import interpolate_reference, to_grid_coords
from tdfields.program import Program, compose_plane_reference, evaluate_reference

__all__ = ["evaluate", "grid_coords", "interpolate", "compose_plane"]


def evaluate(program: Program, factors: Sequence[torch.Tensor], coords: torch.Tensor) -> torch.Tensor:
    """Run ``program``: the Triton kernel where :func:`tdfields.kernels.use_triton` allows it, the numba kernel where
    :func:`tdfields.kernels.use_fused` does, else the reference.

    Args and result as :func:`tdfields.program.evaluate_reference`; the fused path supports first derivatives only.
    """
    if kernels.use_triton(*factors, coords):
        return kernels.triton_evaluate(program, factors, coords)
    if kernels.use_fused(*factors, coords):
        return kernels.fused_evaluate(program, factors, coords)
    return evaluate_reference(program, factors, coords)


def grid_coords(points: torch.Tensor, boxes: Sequence[torch.Tensor], shapes: Sequence[Sequence[int]]) -> torch.Tensor:
    """:func:`tdfields.to_grid_coords` for several grids (levels) at once.

    One fused pass where :mod:`tdfields.kernels` applies (CPU float32/float64 points with numba), else the
    reference stacked per level; values agree bit for bit.

    Args:
        points: ``[N, 3]`` world coordinates in metres (differentiable).
        boxes: one ``(3, 2)`` box in metres per level.
        shapes: one ``(n_x, n_y, n_z)`` per level.

    Returns:
        ``[L, N, 3]`` clamped grid coordinates.
    """
    if kernels.use_fused(points):
        return kernels.fused_grid_coords(points, boxes, shapes)
    return torch.stack([to_grid_coords(points, box, shape) for box, shape in zip(boxes, shapes)])


def interpolate(grid: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Multilinear interpolation of a channels-last grid at continuous indices.

    Uses the fused kernel of :mod:`tdfields.kernels` where it applies (CPU tensors with numba, backend
    ``"auto"`` or ``"numba"``), else :func:`tdfields.interpolation.interpolate_reference`. Same arguments and
    result: ``grid [s_0, ..., s_{d-1}, F]``, ``coords [N, d]`` clamped to ``[0, s_i - 1]`` -> ``[N, F]``.
    """
    if kernels.use_fused(grid, coords):
        return kernels.fused_interpolate(grid, coords)
    return interpolate_reference(grid, coords)


#: above this rank the generated compose kernel falls off a cliff (forward+backward, 1 thread, 64-128 samples a side,
#: 16-32 channels: 0.5-1.1x of the einsum reference up to rank 16, 5-16x slower at 32 and 64;
#: benchmarks/compose_rank.py at f5975fa, since retired), so composition goes to the reference there
FUSED_COMPOSE_MAX_RANK = 16


def compose_plane(u: torch.Tensor, v: torch.Tensor, rank: int, read_at: torch.Tensor | None = None,
                  rows: tuple[tuple[int, int], tuple[int, int]] | None = None) -> torch.Tensor:
    """Rank-k plane from two line factors: ``u [n_a, k*C]``, ``v [n_b, k*C]`` -> ``[n_a, n_b, C]``,
    ``P[a, b, c] = sum_r u[a, r*C + c] v[b, r*C + c]`` (rank-major, channel-minor factors).

    The fused kernel where :func:`tdfields.kernels.use_fused` allows it and ``rank`` is at most
    :data:`FUSED_COMPOSE_MAX_RANK`, else :func:`tdfields.program.compose_plane_reference` (``torch.einsum``).

    ``rows`` (``((a0, a1), (b0, b1))``, half-open) composes the sub-plane of rows ``u[a0:a1]`` and ``v[b0:b1]``
    (``[a1 - a0, b1 - b0, C]``): the same values as composing the slices, and the gradients reach ``u`` and ``v``
    whole, on the fused path without the two slicing steps in the autograd graph (each of which allocates and fills
    a factor-sized gradient of its own).

    ``read_at`` (``[N, 2]`` continuous indices into the (sub-)plane, clamped to it; not differentiated) says where
    the plane will be interpolated: the fused kernel then composes only the cells bilinear interpolation there reads
    and leaves the others 0 (the reference composes every cell). Interpolating the result at those points gives
    the same values either way, bit for bit on the fused path; read it nowhere else.
    """
    if rank <= FUSED_COMPOSE_MAX_RANK and kernels.use_fused(u, v):
        return kernels.fused_compose_plane(u, v, rank, read_at, rows)
    if rows is not None:
        (a0, a1), (b0, b1) = rows
        u, v = u[a0:a1], v[b0:b1]
    return compose_plane_reference(u, v, rank)
