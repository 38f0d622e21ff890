"""The Triton query kernel (opt-in: ``set_backend("triton")``), imported lazily by
:mod:`tdfields.kernels.backend`.

The kernels are generated per program by :mod:`tdfields.kernels.triton_codegen`. They have been checked against
the reference only in Triton's interpreter (``TRITON_INTERPRET=1``, on CPU tensors): this project has not yet had
a GPU to compile and time them on, so ``"auto"`` keeps CUDA tensors on the reference path until they have been.
"""

from __future__ import annotations

import torch
import triton

from tdfields.kernels.second_order import guard_second_order
from tdfields.program import Program

# points per program instance: a [BLOCK, 32] channel tile of float32 is 8 KB of registers per live value
BLOCK = 64


def _sizes(program: Program, grids) -> list[int]:
    return [int(g.shape[a]) for g, axes in zip(grids, program.factor_axes) for a in range(len(axes))]


class TritonProgram(torch.autograd.Function):
    @staticmethod
    def forward(ctx, program, coords, *factors):
        from tdfields.kernels.generated import triton_kernel

        grids = [t.detach().contiguous() for t in factors]
        views = [g.view(-1, g.shape[-1]) for g in grids]
        widths = tuple(v.shape[1] for v in views)
        c = coords.detach().to(grids[0].dtype).contiguous()
        n = c.shape[1]
        out = torch.empty(n, program.out_dim, dtype=grids[0].dtype, device=grids[0].device)
        if n:
            kernel = triton_kernel("forward", program, widths)
            kernel[(triton.cdiv(n, BLOCK),)](*views, c, out, n, *_sizes(program, grids), BLOCK=BLOCK)
        ctx.program, ctx.widths, ctx.coords_dtype = program, widths, coords.dtype
        ctx.save_for_backward(c, *grids)
        return out

    @staticmethod
    def backward(ctx, grad_out):
        from tdfields.kernels.generated import triton_kernel

        c, *grids = ctx.saved_tensors
        want_coords = bool(ctx.needs_input_grad[1])
        want = tuple(bool(w) for w in ctx.needs_input_grad[2:])
        if not want_coords and not any(want):
            return (None, None, *[None] * len(grids))
        with torch.no_grad():
            n = c.shape[1]
            views = [g.view(-1, g.shape[-1]) for g in grids]
            bufs = [torch.zeros_like(v) for v, w in zip(views, want) if w]
            grad_coords = torch.zeros_like(c) if want_coords else torch.zeros((1, 1, 3), dtype=c.dtype,
                                                                                 device=c.device)
            go = grad_out.detach().to(c.dtype).contiguous()
            if n:
                kernel = triton_kernel("backward", ctx.program, ctx.widths, want, want_coords)
                kernel[(triton.cdiv(n, BLOCK),)](*views, c, go, *bufs, grad_coords, n, *_sizes(ctx.program, grids),
                                                 BLOCK=BLOCK)
            it = iter(bufs)
            grads = [next(it).view_as(g) if w else None for g, w in zip(grids, want)]
        return (None, guard_second_order(grad_coords.to(ctx.coords_dtype)) if want_coords else None,
                *[guard_second_order(g) for g in grads])
