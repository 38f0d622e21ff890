"""The guard that makes a second derivative through a fused kernel fail loudly instead of reading zero, and the
first-order backward every backend's query Function inherits (:class:`FirstOrderQuery`).

The kernels' backward passes are themselves not differentiable. Without this guard, autograd with
``create_graph=True`` (an eikonal loss, gradients of normals) would treat the kernels' gradients as constants and
silently drop the second-order term.
"""

from __future__ import annotations

import torch


class _NoSecondDerivative(torch.autograd.Function):
    """Identity whose backward raises: marks gradients the fused kernel cannot differentiate again."""

    @staticmethod
    def forward(ctx, grad, anchor):
        return grad.clone()

    @staticmethod
    def backward(ctx, *_):
        raise RuntimeError("the fused tdfields kernel cannot differentiate twice (eikonal terms, normals' "
                           "gradients): use tdfields.kernels.set_backend('torch') for such losses")


def guard_second_order(grad: torch.Tensor | None) -> torch.Tensor | None:
    """``grad`` unchanged, wrapped so that differentiating it again raises (only when grad mode is on, i.e.
    inside a ``create_graph=True`` backward)."""
    if grad is None or not torch.is_grad_enabled():
        return grad
    return _NoSecondDerivative.apply(grad, torch.zeros((), requires_grad=True))


class FirstOrderQuery(torch.autograd.Function):
    """Base of every backend's query Function, applied as ``apply(program, coords, *factors)``.

    A subclass's ``forward`` runs its kernel, saves the coordinates and factor tensors it ran on
    (``ctx.save_for_backward(coords, *factors)``) and stores, as ``ctx.gradients``, the function
    ``gradients(ctx, grad_out, coords, factors, want_coords, want_factors) -> one gradient or None per input``
    that runs its backward kernel. ``backward`` here returns all None where no input wants a gradient, else those
    gradients computed without a graph, each guarded by :func:`guard_second_order`.
    """

    @staticmethod
    def backward(ctx, grad_out):
        want_coords, want = bool(ctx.needs_input_grad[1]), tuple(bool(w) for w in ctx.needs_input_grad[2:])
        if not want_coords and not any(want):
            return (None,) * len(ctx.needs_input_grad)
        with torch.no_grad():
            coords, *factors = ctx.saved_tensors
            grads = ctx.gradients(ctx, grad_out, coords, factors, want_coords, want)
        return tuple(guard_second_order(g) for g in grads)
