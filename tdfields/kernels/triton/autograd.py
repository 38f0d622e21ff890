"""The Triton kernel's autograd Function and its entry point (opt-in: ``set_backend("triton")``).

The kernels are generated per program by :mod:`tdfields.kernels.triton.source` and loaded by
:mod:`tdfields.kernels.cache`. They have been checked against the reference only in Triton's interpreter
(``TRITON_INTERPRET=1``, on CPU tensors): this project has not yet had a GPU to compile and time them on, so
``"auto"`` keeps CUDA tensors on the reference path until they have been. Importing this module needs no Triton:
:func:`triton_evaluate` raises a clear error where it is missing.
"""

from __future__ import annotations

import torch

from tdfields.kernels.cache import triton_kernel
from tdfields.kernels.dispatch import triton_available
from tdfields.kernels.emitters import check_inputs
from tdfields.kernels.second_order import FirstOrderQuery
from tdfields.program import Program

# points per program instance: a [BLOCK, 32] channel tile of float32 is 8 KB of registers per live value
BLOCK = 64


def _sizes(program: Program, grids) -> list[int]:
    return [int(g.shape[a]) for g, axes in zip(grids, program.factor_axes) for a in range(len(axes))]


def _launch(n: int) -> tuple[int]:
    """The launch grid for ``n`` points: one program instance per ``BLOCK`` of them."""
    import triton

    return (triton.cdiv(n, BLOCK),)


class TritonProgram(FirstOrderQuery):
    @staticmethod
    def forward(ctx, program, coords, *factors):
        grids = [t.detach().contiguous() for t in factors]
        views = [g.view(-1, g.shape[-1]) for g in grids]
        widths = tuple(v.shape[1] for v in views)
        c = coords.detach().to(grids[0].dtype).contiguous()
        n = c.shape[1]
        out = torch.empty(n, program.out_dim, dtype=grids[0].dtype, device=grids[0].device)
        if n:
            kernel = triton_kernel("forward", program, widths)
            kernel[_launch(n)](*views, c, out, n, *_sizes(program, grids), BLOCK=BLOCK)
        ctx.program, ctx.widths, ctx.coords_dtype, ctx.gradients = program, widths, coords.dtype, _triton_gradients
        ctx.save_for_backward(c, *grids)
        return out


def _triton_gradients(ctx, grad_out, c, grids, want_coords: bool, want: tuple[bool, ...]) -> tuple:
    """The gradients of :class:`TritonProgram` (``ctx.gradients``, see
    :class:`tdfields.kernels.second_order.FirstOrderQuery`)."""
    n = c.shape[1]
    views = [g.view(-1, g.shape[-1]) for g in grids]
    bufs = [torch.zeros_like(v) for v, w in zip(views, want) if w]
    grad_coords = torch.zeros_like(c) if want_coords else torch.zeros((1, 1, 3), dtype=c.dtype, device=c.device)
    go = grad_out.detach().to(c.dtype).contiguous()
    if n:
        kernel = triton_kernel("backward", ctx.program, ctx.widths, want, want_coords)
        kernel[_launch(n)](*views, c, go, *bufs, grad_coords, n, *_sizes(ctx.program, grids), BLOCK=BLOCK)
    it = iter(bufs)
    grads = [next(it).view_as(g) if w else None for g, w in zip(grids, want)]
    return (None, grad_coords.to(ctx.coords_dtype) if want_coords else None, *grads)


def triton_evaluate(program: Program, factors, coords: torch.Tensor) -> torch.Tensor:
    """Triton equivalent of :func:`tdfields.program.evaluate_reference` (first derivatives only).

    Same arguments and result as :func:`tdfields.kernels.fused_evaluate`; tensors on one CUDA device (or the CPU
    when interpreting).
    """
    if not triton_available():
        raise RuntimeError("the Triton kernel needs triton; pip install triton, or set_backend('torch')")
    check_inputs(program, factors, coords, "Triton")
    return TritonProgram.apply(program, coords, *factors)
