"""The fused render tail (``rendering.fused``): ESLAM's compositing, the colour sum and the five loss terms as three
autograd Functions, each one kernel per direction, with the pure-PyTorch path of :mod:`slam.core.rendering` and
:mod:`slam.core.losses` as the reference they are tested against. The kernels are numba's on the CPU
(:mod:`slam.core.render_kernels`) and Triton's on CUDA (:mod:`slam.core.render_kernels_triton`), the same
arithmetic in the same order per ray.

:func:`eligible` decides per call, with the backend rules of the field kernels (:mod:`tdfields.kernels.dispatch`):
CPU tensors of one float dtype take the numba kernels where the backend allows fused kernels
(:func:`tdfields.kernels.use_fused`); CUDA tensors take the Triton kernels only with ``TDFIELDS_BACKEND=triton``
(:func:`tdfields.kernels.use_triton`: opt-in until a GPU run has timed them against the reference, as for the
field kernel; the tests run them in Triton's interpreter on CPU tensors); ``TDFIELDS_BACKEND=torch`` selects the
reference everywhere. Sample and measured depths must be without gradient (the tail differentiates the SDF, the
colours, ``beta`` and the rendered depth and colour, which is all the SLAM loop needs). First derivatives only: a
second derivative raises an error.
"""

from __future__ import annotations

import torch
from torch.autograd.function import once_differentiable

from tdfields.kernels import use_fused, use_triton


def _launch(backend: str, name: str, *args: torch.Tensor) -> None:
    """Run kernel ``name`` of ``backend`` (``"numba"``: on numpy views of the CPU tensors; ``"triton"``: on the
    tensors), writing its outputs in place. The modules are imported on first use only (numba compiles or loads
    from its cache, Triton compiles per device)."""
    if backend is None:
        raise RuntimeError("the fused render tail cannot run on these tensors (dtype, device or TDFIELDS_BACKEND); "
                           "check slam.core.fused_render.eligible first, or render with fused=False")
    if backend == "numba":
        from slam.core import render_kernels

        getattr(render_kernels, name)(*(a.numpy() for a in args))
    else:
        from slam.core import render_kernels_triton

        getattr(render_kernels_triton, name)(*args)


def _backend(*tensors: torch.Tensor) -> str | None:
    """``"numba"``, ``"triton"`` or None (the reference) for these tensors (see the module docstring)."""
    if use_fused(*tensors):
        return "numba"
    return "triton" if use_triton(*tensors) else None


def _host(t: torch.Tensor, dtype: torch.dtype | None = None) -> torch.Tensor:
    t = t.detach()
    if dtype is not None and t.dtype != dtype:
        t = t.to(dtype)
    return t if t.is_contiguous() else t.contiguous()


def eligible(*tensors: torch.Tensor, constant: tuple[torch.Tensor, ...] = ()) -> bool:
    """Whether the fused tail runs: ``tensors`` and the ``constant`` ones (which must not need a gradient) in one
    float dtype on one device whose kernel the backend allows (see the module docstring), and no empty batch."""
    if any(t.requires_grad for t in constant) or any(t.numel() == 0 for t in tensors):
        return False
    return _backend(*tensors, *constant) is not None


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
        ctx.backend = _backend(s)
        _launch(ctx.backend, "composite_forward", alpha, zz, weights, depth)
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
        _launch(ctx.backend, "composite_backward", alpha, sig, b, s, zz, gw, gd, grad_sdf, grad_beta)
        shape, dtype = ctx.beta_meta
        beta_grad = grad_beta.sum().reshape(shape).to(dtype) if ctx.needs_input_grad[1] else None
        return grad_sdf, beta_grad, None


class _Color(torch.autograd.Function):
    """``(weights [R, N], rgb [R, N, 3]) -> color [R, 3]``."""

    @staticmethod
    def forward(ctx, weights, rgb):
        w, c = _host(weights), _host(rgb, weights.dtype)
        color = w.new_empty(w.shape[0], 3)
        ctx.backend = _backend(w)
        _launch(ctx.backend, "color_forward", w, c, color)
        ctx.save_for_backward(w, c)
        return color

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_color):
        w, c = ctx.saved_tensors
        grad_weights, grad_rgb = torch.empty_like(w), torch.empty_like(c)
        _launch(ctx.backend, "color_backward", w, c, _host(grad_color, w.dtype), grad_weights, grad_rgb)
        return grad_weights, grad_rgb


class _Loss(torch.autograd.Function):
    """``(sdf [R, N], rendered_depth [R], rendered_color [R, 3], z [R, N], depth [R], color [R, 3], rows, consts)
    -> [5]`` term means (``rows``: per ray 0 unused, 1 colour only, 2 every term)."""

    @staticmethod
    def forward(ctx, sdf, rendered_depth, rendered_color, z, depth, color, rows, consts):
        s = _host(sdf)
        args = (s, _host(z), _host(depth), _host(rendered_depth), _host(rendered_color), _host(color))
        sums, counts = s.new_empty(s.shape[0], 5), torch.empty(s.shape[0], 5, dtype=torch.int32, device=s.device)
        ctx.backend = _backend(s)
        _launch(ctx.backend, "loss_forward", *args, rows, consts, sums, counts)
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
        _launch(ctx.backend, "loss_backward", *args, *ctx.rows_consts, scale, grad_sdf, grad_depth, grad_color)
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
    consts = torch.tensor([truncation, 0.4 * truncation], dtype=sdf.dtype, device=sdf.device)
    return _Loss.apply(sdf, rendered_depth, rendered_color, z, depth, color, use.contiguous(), consts)
