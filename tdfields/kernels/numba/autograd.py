"""The numba kernels' autograd Functions and their entry points (CPU, first derivatives only): query programs,
compose Six-axis planes and map points to grid coordinates.

Each ``torch.autograd.Function`` here hands detached, contiguous tensors to a kernel that
:mod:`tdfields.kernels.cache` compiles for the exact program, widths and dtype (or to the hand-written kernels of
:mod:`tdfields.kernels.numba.coords`), splits the points over :mod:`tdfields.kernels.threads`, and marks its
gradients with :func:`tdfields.kernels.second_order.guard_second_order`. The entry points check their arguments;
which one runs is decided per call by :mod:`tdfields.ops` through :func:`tdfields.kernels.use_fused`. Importing
this module needs no numba: the entry points raise a clear error where it is missing.
"""

from __future__ import annotations

import numpy as np
import torch

from tdfields.kernels.cache import backward_kernel, compose_kernels, forward_kernel
from tdfields.kernels.dispatch import numba_available
from tdfields.kernels.emitters import check_inputs
from tdfields.kernels.second_order import FirstOrderQuery, guard_second_order
from tdfields.kernels.threads import parts_for, run, split
from tdfields.program import Program, single

# Per-thread gradient buffers are only worth it while they are small next to the work; beyond this many
# floats in all the scatter runs in one slot.
_MAX_BUFFER_FLOATS = 1 << 24
# Factor tensors larger than this (floats) get their coordinate gradient and their scatter in two passes: one
# pass touching the factors and their gradient buffers at once overflowed the last-level cache at room scale
# (tri-plane 3 cm: 35 ms vs 14 + 13 ms in two passes, 40k points, 1 thread).
_SPLIT_BACKWARD_FLOATS = 1 << 21


def _require_numba() -> None:
    if not numba_available():
        raise RuntimeError("the fused CPU kernel needs numba; pip install numba, or set_backend('torch')")


def _dtype_name(dtype: torch.dtype) -> str:
    return {torch.float32: "float32", torch.float64: "float64"}[dtype]


def _host(t: torch.Tensor) -> torch.Tensor:
    """``t`` as a tensor numba can read: detached and contiguous, with no torch op where none is needed (a field
    query runs a few of these per factor, and at tracking sizes the dispatch of each costs as much as its work)."""
    if t.requires_grad:
        t = t.detach()
    return t if t.is_contiguous() else t.contiguous()


def _rows(t: torch.Tensor) -> np.ndarray:
    """``[..., F]`` tensor -> ``[rows, F]`` numpy view of the same memory (numpy reshapes need no torch op)."""
    return t.numpy().reshape(-1, t.shape[-1])


def _sizes(program: Program, grids) -> np.ndarray:
    sizes = np.ones((len(grids), 3), np.int64)
    for f, (g, axes) in enumerate(zip(grids, program.factor_axes)):
        sizes[f, : len(axes)] = g.shape[: len(axes)]
    return sizes


class NumbaProgram(FirstOrderQuery):
    @staticmethod
    def forward(ctx, program, coords, *factors):
        dtype = factors[0].dtype
        grids = [_host(t) for t in factors]
        views = [_rows(g) for g in grids]
        widths = tuple(v.shape[1] for v in views)
        c = _host(coords if coords.dtype == dtype else coords.to(dtype))
        sizes = _sizes(program, grids)
        out = torch.empty(c.shape[1], program.out_dim, dtype=dtype)
        kernel = forward_kernel(program, widths, _dtype_name(dtype))
        args = (*views, sizes, c.numpy(), out.numpy())
        run([lambda a=a, b=b: kernel(*args, a, b) for a, b in split(c.shape[1], parts_for(c.shape[1]))])
        ctx.gradients = _numba_gradients
        ctx.program = program
        ctx.widths = widths
        ctx.sizes = sizes
        ctx.coords_dtype = coords.dtype
        ctx.save_for_backward(c, *grids)
        return out


def _numba_gradients(ctx, grad_out, c, grids, want_coords: bool, want: tuple[bool, ...]) -> tuple:
    """The gradients of :class:`NumbaProgram` (``ctx.gradients``, see
    :class:`tdfields.kernels.second_order.FirstOrderQuery`)."""
    dtype = grids[0].dtype
    n_points = c.shape[1]
    total = sum(g.numel() for g, w in zip(grids, want) if w)
    parts = parts_for(n_points)
    # one scatter buffer set per thread pays off while it stays small next to the work; else one serial pass
    if total * parts > _MAX_BUFFER_FLOATS:
        parts = 1
    rows = [(g.numel() // g.shape[-1], g.shape[-1]) for g in grids]
    buffers = [[torch.zeros(rows[f], dtype=dtype) for f in range(len(grids)) if want[f]] for _ in range(parts)]
    grad_coords = torch.zeros_like(c) if want_coords else torch.zeros((1, 1, 3), dtype=dtype)
    views = [_rows(g) for g in grids]
    go = _host(grad_out if grad_out.dtype == dtype else grad_out.to(dtype))
    chans = np.asarray([ctx.widths[t[0]] // k for t, k in zip(ctx.program.terms, ctx.program.ranks)], np.int64)
    common = (*views, ctx.sizes, chans, c.numpy(), go.numpy())
    passes = [(want, want_coords)]
    if want_coords and any(want) and sum(g.numel() for g in grids) > _SPLIT_BACKWARD_FLOATS:
        passes = [(tuple(False for _ in want), True), (want, False)]
    for want_f, want_c in passes:
        kernel = backward_kernel(ctx.program, ctx.widths, want_f, want_c, _dtype_name(dtype))
        run([lambda a=a, b=b, bufs=bufs: kernel(*common, *[t.numpy() for t in bufs] if any(want_f) else (),
                                                grad_coords.numpy(), a, b)
             for (a, b), bufs in zip(split(n_points, parts), buffers)])
    summed = iter([sum(bs[1:], bs[0]) if parts > 1 else bs[0] for bs in zip(*buffers)])
    grads = [next(summed).view_as(g) if w else None for g, w in zip(grids, want)]
    return (None, grad_coords.to(ctx.coords_dtype) if want_coords else None, *grads)


def fused_evaluate(program: Program, factors, coords: torch.Tensor) -> torch.Tensor:
    """Fused equivalent of :func:`tdfields.program.evaluate_reference` (CPU, first derivatives only).

    Args:
        program: the query structure (at most 3 factors per term).
        factors: one channels-last tensor per factor.
        coords: ``[L, N, 3]`` clamped grid coordinates, one set per level.

    Returns:
        ``[N, program.out_dim]``.
    """
    _require_numba()
    check_inputs(program, factors, coords, "fused")
    return NumbaProgram.apply(program, coords, *factors)


def _live_cells(read_at: torch.Tensor | None, n_a: int, n_b: int) -> np.ndarray | None:
    """``[n_a * n_b]`` uint8 flags of the cells interpolation at ``read_at [N, 2]`` reads, or None for all of
    them (no ``read_at``, or a non-finite coordinate in it)."""
    if read_at is None:
        return None
    from tdfields.kernels.numba.cells import read_cells

    live = np.zeros(n_a * n_b, np.uint8)
    return live if read_cells(_host(read_at).numpy(), n_a, n_b, live) else None


class NumbaCompose(torch.autograd.Function):
    @staticmethod
    def forward(ctx, u, v, rank, read_at=None, rows=None):
        (a0, a1), (b0, b1) = rows if rows is not None else ((0, u.shape[0]), (0, v.shape[0]))
        # row ranges of contiguous factors are contiguous views: nothing is copied for a sub-plane
        uc, vc = u.detach()[a0:a1].contiguous(), v.detach()[b0:b1].contiguous()
        channels = uc.shape[1] // rank
        plane = torch.empty(uc.shape[0], vc.shape[0], channels, dtype=uc.dtype)
        mod = compose_kernels(rank, channels, _dtype_name(uc.dtype))
        flat = plane.view(-1, channels).numpy()
        live = _live_cells(read_at, uc.shape[0], vc.shape[0])
        # every cell, or only those flagged live: the same FMA chain either way
        kernel, flags = (mod.compose_forward, ()) if live is None else (mod.compose_forward_cells, (live,))
        run([lambda a=a, b=b: kernel(uc.numpy(), vc.numpy(), flat, *flags, a, b)
             for a, b in split(uc.shape[0], parts_for(uc.shape[0] * vc.shape[0]))])
        ctx.save_for_backward(uc, vc)
        ctx.rank = rank
        ctx.rows = (a0, b0, tuple(u.shape), tuple(v.shape))
        return plane

    @staticmethod
    def backward(ctx, grad_plane):
        uc, vc = ctx.saved_tensors
        want_u, want_v = bool(ctx.needs_input_grad[0]), bool(ctx.needs_input_grad[1])
        a0, b0, shape_u, shape_v = ctx.rows
        with torch.no_grad():
            gp = grad_plane.detach().to(uc.dtype).contiguous()
            mod = compose_kernels(ctx.rank, gp.shape[-1], _dtype_name(uc.dtype))
            flat = gp.view(-1, gp.shape[-1]).numpy()
            ranges = split(uc.shape[0], parts_for(uc.shape[0] * vc.shape[0]))
            # whole-factor gradients: the kernel writes the sub-plane's rows of them, the rest stays 0 (as slicing
            # gives); every row of u's when the plane spans them all
            gu = gv = None
            if want_u:
                gu = torch.empty_like(uc) if tuple(uc.shape) == shape_u else uc.new_zeros(shape_u)
            if want_v:
                gv = vc.new_zeros(shape_v)
            none = torch.zeros((1, 1), dtype=uc.dtype)
            gu_rows = gu[a0:a0 + uc.shape[0]] if want_u else none
            gvs = [gv[b0:b0 + vc.shape[0]] if want_v else none]  # one part of v's gradient per thread, summed below
            gvs += [torch.zeros_like(vc) if want_v else none for _ in ranges[1:]]
            run([lambda a=a, b=b, part=part: mod.compose_backward(uc.numpy(), vc.numpy(), flat, gu_rows.numpy(),
                                                                  part.numpy(), want_u, want_v, a, b)
                 for (a, b), part in zip(ranges, gvs)])
            for part in gvs[1:] if want_v else []:
                gvs[0].add_(part)
        return guard_second_order(gu), guard_second_order(gv), None, None, None


def fused_compose_plane(u: torch.Tensor, v: torch.Tensor, rank: int, read_at: torch.Tensor | None = None,
                        rows: tuple[tuple[int, int], tuple[int, int]] | None = None) -> torch.Tensor:
    """Fused equivalent of :func:`tdfields.program.compose_plane_reference` (CPU, first derivatives only): the
    rank-k plane ``[n_a, n_b, C]`` of two line factors ``u [n_a, k*C]``, ``v [n_b, k*C]``; with ``rows``
    (``((a0, a1), (b0, b1))``) the sub-plane of ``u[a0:a1]`` and ``v[b0:b1]``, gradients to the whole factors; with
    ``read_at`` (``[N, 2]`` continuous indices into the (sub-)plane, no gradient) only the cells interpolation there
    reads, the others 0. :func:`tdfields.ops.compose_plane` picks it or the reference per call."""
    _require_numba()
    if read_at is not None and (read_at.dim() != 2 or read_at.shape[1] != 2):
        raise ValueError(f"read_at must be [N, 2] plane coordinates, got {tuple(read_at.shape)}")
    if rows is not None:
        (a0, a1), (b0, b1) = rows
        if not (0 <= a0 < a1 <= u.shape[0] and 0 <= b0 < b1 <= v.shape[0]):
            raise ValueError(f"rows {rows} are not inside the factors' {u.shape[0]} and {v.shape[0]} rows")
        rows = ((int(a0), int(a1)), (int(b0), int(b1)))
    return NumbaCompose.apply(u, v, rank, None if read_at is None else read_at.detach(), rows)


class NumbaGridCoords(torch.autograd.Function):
    @staticmethod
    def forward(ctx, points, lo, extent, top):
        from tdfields.kernels.numba.coords import grid_coords_forward

        p = _host(points)
        out = torch.empty(lo.shape[0], p.shape[0], 3, dtype=p.dtype)
        args = (p.numpy(), lo, extent, top, out.numpy())
        run([lambda a=a, b=b: grid_coords_forward(*args, a, b) for a, b in split(p.shape[0], parts_for(p.shape[0]))])
        ctx.save_for_backward(p)
        ctx.box = (lo, extent, top)
        return out

    @staticmethod
    def backward(ctx, grad):
        from tdfields.kernels.numba.coords import grid_coords_backward

        if not ctx.needs_input_grad[0]:
            return None, None, None, None
        (p,) = ctx.saved_tensors
        with torch.no_grad():
            g = _host(grad if grad.dtype == p.dtype else grad.to(p.dtype))
            out = torch.empty_like(p)
            args = (p.numpy(), *ctx.box, g.numpy(), out.numpy())
            run([lambda a=a, b=b: grid_coords_backward(*args, a, b)
                 for a, b in split(p.shape[0], parts_for(p.shape[0]))])
        return guard_second_order(out), None, None, None


def fused_grid_coords(points: torch.Tensor, boxes, shapes) -> torch.Tensor:
    """Fused equivalent of stacking :func:`tdfields.to_grid_coords` over levels (first derivatives only).

    Args:
        points: ``[N, 3]`` world metres, float32 or float64 on the CPU (differentiable).
        boxes: one ``(3, 2)`` box per level, metres.
        shapes: one ``(n_x, n_y, n_z)`` per level.

    Returns:
        ``[L, N, 3]`` clamped grid coordinates, dtype of ``points``.
    """
    _require_numba()
    dt = np.float32 if points.dtype == torch.float32 else np.float64
    # the per-level constants in numpy: a dozen tiny torch ops per query otherwise (boxes are buffers, no grad)
    box = np.stack([np.asarray(b.detach().cpu() if b.requires_grad else b.cpu(), dtype=dt) for b in boxes])
    lo = np.ascontiguousarray(box[:, :, 0])
    extent = np.ascontiguousarray(box[:, :, 1] - box[:, :, 0])
    top = np.asarray([[n - 1 for n in s] for s in shapes], dtype=dt)
    return NumbaGridCoords.apply(points, lo, extent, top)


def fused_interpolate(grid: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Fused equivalent of :func:`tdfields.interpolation.interpolate_reference` (first derivatives only).

    ``grid [s_0, ..., s_{d-1}, F]`` and ``coords [N, d]`` -> ``[N, F]``: a one-factor, one-term program.
    """
    d = coords.shape[-1]
    program = single([tuple(range(d))], [(0,)], [1], grid.shape[-1])
    padded = torch.cat((coords, coords.new_zeros(coords.shape[0], 3 - d)), -1) if d < 3 else coords
    return fused_evaluate(program, [grid], padded[None])
