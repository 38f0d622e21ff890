"""The fused render tail (``rendering.fused``): ESLAM's compositing, the colour sum and the five loss terms as three
autograd Functions, each one numba kernel per direction (:mod:`slam.core.render_kernels`), with the pure-PyTorch path of
:mod:`slam.core.rendering` and :mod:`slam.core.losses` as the reference they are tested against.

:func:`eligible` decides per call: CPU tensors of one float dtype, the tdfields backend allowing fused kernels
(:func:`tdfields.kernels.use_fused`; ``TDFIELDS_BACKEND=torch`` selects the reference everywhere), and sample and
measured depths without gradient (the tail differentiates the SDF, the colours, ``beta`` and the rendered depth and
colour, which is all the SLAM loop needs). First derivatives only: a second derivative raises an error.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from tdfields.kernels import use_fused


def _kernels():
    from slam.core import render_kernels  # numba compiles (or loads from its cache) on first use only

    return render_kernels


def _host(t: torch.Tensor, dtype: torch.dtype | None = None) -> torch.Tensor:
    t = t.detach()
    if dtype is not None and t.dtype != dtype:
        t = t.to(dtype)
    return t if t.is_contiguous() else t.contiguous()


def eligible(*tensors: torch.Tensor, constant: tuple[torch.Tensor, ...] = ()) -> bool:
    """Whether the fused tail runs: ``tensors`` and the ``constant`` ones (which must not need a gradient) on the
    CPU in one float dtype, the backend allowing fused kernels, and no empty batch."""
    if any(t.requires_grad for t in constant) or any(t.numel() == 0 for t in tensors):
        return False
    return use_fused(*tensors, *constant)


class _Composite(torch.autograd.Function):
    """``(sdf [R, N], beta [], z [R, N]) -> (weights [R, N], depth [R])``."""

    @staticmethod
    def forward(ctx, sdf, beta, z):
        s, zz = _host(sdf), _host(z)
        b = _host(beta, s.dtype).reshape(1)
        # the same ops as slam.core.rendering.sdf_to_alpha, so alpha is the reference's bit for bit
        sig = torch.sigmoid(-b * s)
        alpha = 1.0 - torch.exp(-(b * sig))
        weights, depth = torch.empty_like(s), s.new_empty(s.shape[0])
        _kernels().composite_forward(alpha.numpy(), zz.numpy(), weights.numpy(), depth.numpy())
        ctx.save_for_backward(alpha, sig, b, s, zz)
        ctx.beta_meta = (beta.shape, beta.dtype)
        return weights, depth

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_weights, grad_depth):
        alpha, sig, b, s, zz = ctx.saved_tensors
        R, N = s.shape
        gw = s.new_zeros(R, N) if grad_weights is None else _host(grad_weights, s.dtype)
        gd = s.new_zeros(R) if grad_depth is None else _host(grad_depth, s.dtype)
        grad_sdf, grad_beta = torch.empty_like(s), s.new_empty(R)
        _kernels().composite_backward(alpha.numpy(), sig.numpy(), b.numpy(), s.numpy(), zz.numpy(), gw.numpy(),
                                      gd.numpy(), grad_sdf.numpy(), grad_beta.numpy())
        shape, dtype = ctx.beta_meta
        beta_grad = grad_beta.sum().reshape(shape).to(dtype) if ctx.needs_input_grad[1] else None
        return grad_sdf, beta_grad, None


class _Color(torch.autograd.Function):
    """``(weights [R, N], rgb [R, N, 3]) -> color [R, 3]``."""

    @staticmethod
    def forward(ctx, weights, rgb):
        w, c = _host(weights), _host(rgb, weights.dtype)
        color = w.new_empty(w.shape[0], 3)
        _kernels().color_forward(w.numpy(), c.numpy(), color.numpy())
        ctx.save_for_backward(w, c)
        return color

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_color):
        w, c = ctx.saved_tensors
        grad_weights, grad_rgb = torch.empty_like(w), torch.empty_like(c)
        _kernels().color_backward(w.numpy(), c.numpy(), _host(grad_color, w.dtype).numpy(), grad_weights.numpy(),
                                  grad_rgb.numpy())
        return grad_weights, grad_rgb


class _Loss(torch.autograd.Function):
    """``(sdf [R, N], rendered_depth [R], rendered_color [R, 3], z [R, N], depth [R], color [R, 3], rows, consts)
    -> [5]`` term means (``rows``: per ray 0 unused, 1 colour only, 2 every term)."""

    @staticmethod
    def forward(ctx, sdf, rendered_depth, rendered_color, z, depth, color, rows, consts):
        s = _host(sdf)
        args = (s, _host(z), _host(depth), _host(rendered_depth), _host(rendered_color), _host(color))
        sums, counts = s.new_empty(s.shape[0], 5), torch.empty(s.shape[0], 5, dtype=torch.int64)
        _kernels().loss_forward(*(a.numpy() for a in args), rows, consts, sums.numpy(), counts.numpy())
        count = counts.sum(0).clamp(min=1).to(s.dtype)
        ctx.save_for_backward(*args, count)
        ctx.rows_consts = (rows, consts)
        return sums.sum(0) / count

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_terms):
        *args, count = ctx.saved_tensors
        s = args[0]
        scale = (_host(grad_terms, s.dtype) / count).contiguous()
        grad_sdf, grad_depth, grad_color = torch.empty_like(s), s.new_empty(s.shape[0]), s.new_empty(s.shape[0], 3)
        _kernels().loss_backward(*(a.numpy() for a in args), *ctx.rows_consts, scale.numpy(), grad_sdf.numpy(),
                                 grad_depth.numpy(), grad_color.numpy())
        return grad_sdf, grad_depth, grad_color, None, None, None, None, None


def composite(sdf: torch.Tensor, beta: torch.Tensor | float, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(weights [R, N], depth [R])`` composited from SDF samples ``sdf [R, N]`` at depths ``z [R, N]``
    (metres), fused (check :func:`eligible` first). Differentiable in ``sdf`` and a tensor ``beta``."""
    beta_t = beta if isinstance(beta, torch.Tensor) else torch.tensor(float(beta), dtype=sdf.dtype)
    return _Composite.apply(sdf, beta_t, z)


def color_sum(weights: torch.Tensor, rgb: torch.Tensor) -> torch.Tensor:
    """``[R, 3]`` colour ``sum_n w_n rgb_n`` of weights ``[R, N]`` and sample colours ``rgb [R, N, 3]``, fused
    (check :func:`eligible` first). Differentiable in both."""
    return _Color.apply(weights, rgb)


def loss_terms(sdf: torch.Tensor, z: torch.Tensor, rendered_depth: torch.Tensor, rendered_color: torch.Tensor,
               depth: torch.Tensor, color: torch.Tensor, truncation: float, depth_rows: torch.Tensor,
               rows: torch.Tensor | None = None) -> torch.Tensor:
    """``[5]`` unweighted means of the free-space, centre, tail, depth and colour terms
    (:data:`slam.core.losses.LOSS_TERMS` order), fused (check :func:`eligible` first).

    Args:
        sdf, z: ``[R, N]``; rendered_depth, depth: ``[R]`` metres; rendered_color, color: ``[R, 3]``.
        depth_rows: ``[R]`` bool, the rays of the SDF and depth terms; rows: ``[R]`` bool, the rays used at all
            (default every ray), so the colour term is over ``rows`` and the others over ``rows & depth_rows``.
    """
    use = depth_rows.to(torch.uint8) + 1
    if rows is not None:
        use = use * rows.to(torch.uint8)
    consts = np.array([truncation, 0.4 * truncation], dtype=sdf.detach().numpy().dtype)
    return _Loss.apply(sdf, rendered_depth, rendered_color, z, depth, color, use.contiguous().numpy(), consts)
