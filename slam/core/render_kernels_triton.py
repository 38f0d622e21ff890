"""Triton kernels for the render tail (imported lazily by :mod:`slam.core.fused_render`, needs triton): the same
compositing, colour sum and five loss terms as the numba kernels of :mod:`slam.core.render_kernels`, forward and
backward, for CUDA tensors (and CPU tensors under ``TRITON_INTERPRET=1``, which is how the tests run them here).

Each program instance takes ``BLOCK`` rays and walks their ``N`` samples in order, as the numba kernels walk one
ray: the same arithmetic in the same dtype and order per ray, so values agree with the numba kernels and the
PyTorch reference to a few ulp. Per-launch wrappers at the bottom take torch tensors (contiguous, one device, one
float dtype) with the numba kernels' signatures; outputs are written in place.

The scalars the kernels compare against (the truncation ``T``, the centre band, the loss scales, ``beta``) arrive
as tensors of the rays' dtype, so float64 runs compare in float64 as the reference does (a Python float argument
would be a float32 scalar in Triton).
"""

from __future__ import annotations

import torch
import triton
import triton.language as tl

#: rays per program instance (Triton's default 4 warps are 128 threads: one ray each)
BLOCK = 128


@triton.jit
def _composite_forward(alpha, z, weights, depth, R, N, BLOCK: tl.constexpr):  # pragma: no cover - compiled
    r = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    m = r < R
    base = r * N
    t = tl.full([BLOCK], 1.0, alpha.dtype.element_ty)
    d = tl.zeros([BLOCK], alpha.dtype.element_ty)
    for n in range(N):
        a = tl.load(alpha + base + n, mask=m, other=0.0)
        w = a * t
        tl.store(weights + base + n, w, mask=m)
        d += w * tl.load(z + base + n, mask=m, other=0.0)
        t = t * (1.0 - a + 1e-10)
    tl.store(depth + r, d, mask=m)


@triton.jit
def _composite_backward(alpha, sig, beta, sdf, z, grad_weights, grad_depth, trans, grad_sdf, grad_beta, R, N,
                        BLOCK: tl.constexpr):  # pragma: no cover - compiled
    r = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    m = r < R
    base = r * N
    b = tl.load(beta)
    t = tl.full([BLOCK], 1.0, alpha.dtype.element_ty)
    for n in range(N):
        tl.store(trans + base + n, t, mask=m)
        t = t * (1.0 - tl.load(alpha + base + n, mask=m, other=0.0) + 1e-10)
    tl.debug_barrier()  # the transmittances stored above are read back below, whichever thread wrote them
    gd = tl.load(grad_depth + r, mask=m, other=0.0)
    s_acc = tl.zeros([BLOCK], alpha.dtype.element_ty)
    gb = tl.zeros([BLOCK], alpha.dtype.element_ty)
    for i in range(N):
        n = N - 1 - i
        a = tl.load(alpha + base + n, mask=m, other=0.0)
        g = tl.load(grad_weights + base + n, mask=m, other=0.0) + gd * tl.load(z + base + n, mask=m, other=0.0)
        ga = tl.load(trans + base + n, mask=m, other=0.0) * (g - s_acc)
        s_acc = g * a + (1.0 - a + 1e-10) * s_acc
        e = 1.0 - a
        q = tl.load(sig + base + n, mask=m, other=0.0)
        ds = q * (1.0 - q)
        tl.store(grad_sdf + base + n, ga * e * (-b * b * ds), mask=m)
        gb += ga * e * (q - b * tl.load(sdf + base + n, mask=m, other=0.0) * ds)
    tl.store(grad_beta + r, gb, mask=m)


@triton.jit
def _color_forward(weights, rgb, color, R, N, BLOCK: tl.constexpr):  # pragma: no cover - compiled
    r = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    m = r < R
    c0 = tl.zeros([BLOCK], weights.dtype.element_ty)
    c1 = tl.zeros([BLOCK], weights.dtype.element_ty)
    c2 = tl.zeros([BLOCK], weights.dtype.element_ty)
    for n in range(N):
        w = tl.load(weights + r * N + n, mask=m, other=0.0)
        k = (r * N + n) * 3
        c0 += w * tl.load(rgb + k, mask=m, other=0.0)
        c1 += w * tl.load(rgb + k + 1, mask=m, other=0.0)
        c2 += w * tl.load(rgb + k + 2, mask=m, other=0.0)
    tl.store(color + r * 3, c0, mask=m)
    tl.store(color + r * 3 + 1, c1, mask=m)
    tl.store(color + r * 3 + 2, c2, mask=m)


@triton.jit
def _color_backward(weights, rgb, grad_color, grad_weights, grad_rgb, R, N, BLOCK: tl.constexpr):  # pragma: no cover
    r = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    m = r < R
    g0 = tl.load(grad_color + r * 3, mask=m, other=0.0)
    g1 = tl.load(grad_color + r * 3 + 1, mask=m, other=0.0)
    g2 = tl.load(grad_color + r * 3 + 2, mask=m, other=0.0)
    for n in range(N):
        w = tl.load(weights + r * N + n, mask=m, other=0.0)
        k = (r * N + n) * 3
        gw = g0 * tl.load(rgb + k, mask=m, other=0.0) + g1 * tl.load(rgb + k + 1, mask=m, other=0.0)
        gw += g2 * tl.load(rgb + k + 2, mask=m, other=0.0)
        tl.store(grad_weights + r * N + n, gw, mask=m)
        tl.store(grad_rgb + k, g0 * w, mask=m)
        tl.store(grad_rgb + k + 1, g1 * w, mask=m)
        tl.store(grad_rgb + k + 2, g2 * w, mask=m)


@triton.jit
def _regions(zz, D, T, band_width, full):  # pragma: no cover - compiled
    """``(front, centre, tail)`` of samples at depths ``zz`` on rays of measured depth ``D`` that take every term
    (``full``): free space ``zz < D - T``, the centre ``|zz - D| < band_width``, the rest of ``|zz - D| <= T``
    (:func:`slam.core.render_kernels._regions`)."""
    off = tl.abs(zz - D)
    return full & (zz < D - T), full & (off < band_width), full & (off >= band_width) & (off <= T)


@triton.jit
def _loss_forward(sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, sums, counts, R, N,
                  BLOCK: tl.constexpr):  # pragma: no cover - compiled
    r = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    m = r < R
    use = tl.load(rows + r, mask=m, other=0).to(tl.int32)
    T = tl.load(consts)
    band_width = tl.load(consts + 1)
    zero = tl.zeros([BLOCK], sdf.dtype.element_ty)
    c = zero
    for ch in range(3):
        err = tl.load(rendered_color + r * 3 + ch, mask=m, other=0.0) - tl.load(color + r * 3 + ch, mask=m, other=0.0)
        c += err * err
    on = use >= 1
    full = use == 2
    D = tl.load(depth + r, mask=m, other=0.0)
    s_fs = zero
    s_c = zero
    s_t = zero
    n_fs = tl.zeros([BLOCK], tl.int32)
    n_c = tl.zeros([BLOCK], tl.int32)
    n_t = tl.zeros([BLOCK], tl.int32)
    for n in range(N):
        s = tl.load(sdf + r * N + n, mask=m, other=0.0)
        zz = tl.load(z + r * N + n, mask=m, other=0.0)
        front, centre, tail = _regions(zz, D, T, band_width, full)
        err = zz + s * T - D
        s_fs += tl.where(front, (s - 1.0) * (s - 1.0), 0.0)
        s_c += tl.where(centre, err * err, 0.0)
        s_t += tl.where(tail, err * err, 0.0)
        n_fs += front.to(tl.int32)
        n_c += centre.to(tl.int32)
        n_t += tail.to(tl.int32)
    de = tl.load(rendered_depth + r, mask=m, other=0.0) - D
    k = r * 5
    tl.store(sums + k, s_fs, mask=m)
    tl.store(sums + k + 1, s_c, mask=m)
    tl.store(sums + k + 2, s_t, mask=m)
    tl.store(sums + k + 3, tl.where(full, de * de, 0.0), mask=m)
    tl.store(sums + k + 4, tl.where(on, c, 0.0), mask=m)
    tl.store(counts + k, n_fs, mask=m)
    tl.store(counts + k + 1, n_c, mask=m)
    tl.store(counts + k + 2, n_t, mask=m)
    tl.store(counts + k + 3, full.to(tl.int32), mask=m)
    tl.store(counts + k + 4, on.to(tl.int32) * 3, mask=m)


@triton.jit
def _loss_backward(sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, scale, grad_sdf, grad_depth,
                   grad_color, R, N, BLOCK: tl.constexpr):  # pragma: no cover - compiled
    r = (tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    m = r < R
    use = tl.load(rows + r, mask=m, other=0).to(tl.int32)
    T = tl.load(consts)
    band_width = tl.load(consts + 1)
    on = use >= 1
    full = use == 2
    for ch in range(3):
        err = tl.load(rendered_color + r * 3 + ch, mask=m, other=0.0) - tl.load(color + r * 3 + ch, mask=m, other=0.0)
        tl.store(grad_color + r * 3 + ch, tl.where(on, tl.load(scale + 4) * 2.0 * err, 0.0), mask=m)
    D = tl.load(depth + r, mask=m, other=0.0)
    de = tl.load(rendered_depth + r, mask=m, other=0.0) - D
    tl.store(grad_depth + r, tl.where(full, tl.load(scale + 3) * 2.0 * de, 0.0), mask=m)
    w_fs = tl.load(scale)
    w_c = tl.load(scale + 1)
    w_t = tl.load(scale + 2)
    for n in range(N):
        s = tl.load(sdf + r * N + n, mask=m, other=0.0)
        zz = tl.load(z + r * N + n, mask=m, other=0.0)
        front, centre, tail = _regions(zz, D, T, band_width, full)
        g = tl.where(front, w_fs * 2.0 * (s - 1.0), 0.0)
        band = tl.where(centre, w_c, tl.where(tail, w_t, 0.0))
        g += tl.where(centre | tail, band * 2.0 * (zz + s * T - D) * T, 0.0)
        tl.store(grad_sdf + r * N + n, g, mask=m)


def _grid(R: int) -> tuple[int]:
    return (triton.cdiv(R, BLOCK),)


def composite_forward(alpha, z, weights, depth):
    """``alpha, z [R, N]`` -> ``weights [R, N]``, ``depth [R]`` (:func:`slam.core.render_kernels.composite_forward`)."""
    R, N = alpha.shape
    _composite_forward[_grid(R)](alpha, z, weights, depth, R, N, BLOCK=BLOCK)


def composite_backward(alpha, sig, beta, sdf, z, grad_weights, grad_depth, grad_sdf, grad_beta):
    """:func:`slam.core.render_kernels.composite_backward` (``beta [1]``; the transmittances in a scratch buffer)."""
    R, N = alpha.shape
    trans = torch.empty_like(alpha)
    _composite_backward[_grid(R)](alpha, sig, beta, sdf, z, grad_weights, grad_depth, trans, grad_sdf, grad_beta,
                                  R, N, BLOCK=BLOCK)


def color_forward(weights, rgb, color):
    """``weights [R, N]``, ``rgb [R, N, 3]`` -> ``color [R, 3]``."""
    R, N = weights.shape
    _color_forward[_grid(R)](weights, rgb, color, R, N, BLOCK=BLOCK)


def color_backward(weights, rgb, grad_color, grad_weights, grad_rgb):
    """``grad_color [R, 3]`` -> ``grad_weights [R, N]``, ``grad_rgb [R, N, 3]``."""
    R, N = weights.shape
    _color_backward[_grid(R)](weights, rgb, grad_color, grad_weights, grad_rgb, R, N, BLOCK=BLOCK)


def loss_forward(sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, sums, counts):
    """:func:`slam.core.render_kernels.loss_forward` (``rows [R]`` uint8, ``consts [2]``, ``counts [R, 5]`` int32)."""
    R, N = sdf.shape
    _loss_forward[_grid(R)](sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, sums, counts, R, N,
                            BLOCK=BLOCK)


def loss_backward(sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, scale, grad_sdf, grad_depth,
                  grad_color):
    """:func:`slam.core.render_kernels.loss_backward` (``scale [5]`` in the rays' dtype)."""
    R, N = sdf.shape
    _loss_backward[_grid(R)](sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, scale, grad_sdf,
                             grad_depth, grad_color, R, N, BLOCK=BLOCK)
