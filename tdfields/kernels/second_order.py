"""The guard that makes a second derivative through a fused kernel fail loudly instead of reading zero.

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
