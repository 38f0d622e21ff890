"""Hand-written numba kernels for the render tail (imported lazily by :mod:`slam.core.fused_render`, needs numba):
ESLAM's compositing of weights and depth, the colour sum, and the five loss terms, forward and backward, one pass
per ray.

The reference (:mod:`slam.core.rendering`, :mod:`slam.core.losses`) builds these from some forty broadcast ops on
``[R, N]`` tensors (cumulative products, concatenations, masks, pooled means), and autograd adds as many again, each
a dispatch costing more than its arithmetic at tracking sizes (400 rays x 24 samples). The arithmetic here repeats
the reference's in the same dtype and order, except for the sums over samples and rays, whose order differs, so
values agree to a few ulp, not bit for bit.

The compositing backward runs without a division: with ``q_n = 1 - alpha_n + 1e-10`` and ``T_n`` the
transmittance before sample ``n``, ``dL/dalpha_n = T_n (g_n - S_n)`` where ``g_n = dL/dw_n`` and
``S_n = sum_{m > n} g_m alpha_m prod_{n < k < m} q_k`` (so ``S_{n-1} = g_n alpha_n + q_n S_n``); the reference's
``cumprod`` backward divides by ``q_n``.

No ``fastmath``: a NaN must stay NaN, as in the reference.
"""

from __future__ import annotations

from numba import njit


@njit(nogil=True, cache=True)
def composite_forward(alpha, z, weights, depth):  # pragma: no cover - compiled
    """``alpha, z [R, N]`` -> ``weights [R, N]`` (``alpha_n prod_{k<n} (1 - alpha_k + 1e-10)``, the product taken
    in the reference's order) and ``depth [R]`` (``sum_n w_n z_n``)."""
    one = alpha.dtype.type(1.0)
    tiny = alpha.dtype.type(1e-10)
    for r in range(alpha.shape[0]):
        t = one
        d = alpha.dtype.type(0.0)
        for n in range(alpha.shape[1]):
            a = alpha[r, n]
            w = a * t
            weights[r, n] = w
            d += w * z[r, n]
            t = t * (one - a + tiny)
        depth[r] = d


@njit(nogil=True, cache=True)
def composite_backward(alpha, sig, beta, sdf, z, grad_weights, grad_depth, grad_sdf, grad_beta):  # pragma: no cover - compiled
    """Gradients of :func:`composite_forward` through ``alpha = 1 - exp(-beta sig)``, ``sig = sigmoid(-beta s)``:
    ``grad_weights [R, N]``, ``grad_depth [R]`` -> ``grad_sdf [R, N]`` and ``grad_beta [R]`` (per ray; the caller
    sums). The transmittance is rebuilt by the forward's products (``weights / alpha`` would divide by zero where
    a sample is empty), held in ``grad_sdf`` until each entry is overwritten."""
    one = alpha.dtype.type(1.0)
    zero = alpha.dtype.type(0.0)
    tiny = alpha.dtype.type(1e-10)
    b = beta[0]
    N = alpha.shape[1]
    for r in range(alpha.shape[0]):
        t = one
        for n in range(N):
            grad_sdf[r, n] = t  # the transmittance, overwritten below once used
            t = t * (one - alpha[r, n] + tiny)
        gd = grad_depth[r]
        s_acc = zero
        gb = zero
        for n in range(N - 1, -1, -1):
            a = alpha[r, n]
            g = grad_weights[r, n] + gd * z[r, n]
            ga = grad_sdf[r, n] * (g - s_acc)
            s_acc = g * a + (one - a + tiny) * s_acc
            # alpha = 1 - exp(-sigma), sigma = b sig(-b s): d alpha / d sigma = 1 - alpha, sig' = sig (1 - sig)
            e = one - a
            q = sig[r, n]
            ds = q * (one - q)
            grad_sdf[r, n] = ga * e * (-b * b * ds)
            gb += ga * e * (q - b * sdf[r, n] * ds)
        grad_beta[r] = gb


@njit(nogil=True, cache=True)
def color_forward(weights, rgb, color):  # pragma: no cover - compiled
    """``weights [R, N]``, ``rgb [R, N, 3]`` -> ``color [R, 3]`` (``sum_n w_n rgb_n``)."""
    zero = weights.dtype.type(0.0)
    for r in range(weights.shape[0]):
        c0 = zero
        c1 = zero
        c2 = zero
        for n in range(weights.shape[1]):
            w = weights[r, n]
            c0 += w * rgb[r, n, 0]
            c1 += w * rgb[r, n, 1]
            c2 += w * rgb[r, n, 2]
        color[r, 0] = c0
        color[r, 1] = c1
        color[r, 2] = c2


@njit(nogil=True, cache=True)
def color_backward(weights, rgb, grad_color, grad_weights, grad_rgb):  # pragma: no cover - compiled
    """Gradients of :func:`color_forward`: ``grad_color [R, 3]`` -> ``grad_weights [R, N]``, ``grad_rgb [R, N, 3]``."""
    for r in range(weights.shape[0]):
        g0 = grad_color[r, 0]
        g1 = grad_color[r, 1]
        g2 = grad_color[r, 2]
        for n in range(weights.shape[1]):
            w = weights[r, n]
            grad_weights[r, n] = g0 * rgb[r, n, 0] + g1 * rgb[r, n, 1] + g2 * rgb[r, n, 2]
            grad_rgb[r, n, 0] = g0 * w
            grad_rgb[r, n, 1] = g1 * w
            grad_rgb[r, n, 2] = g2 * w


@njit(nogil=True, cache=True, inline="always")
def _regions(z, D, T, band):  # pragma: no cover - compiled
    """``(in free space, band)`` of a sample at depth ``z`` on a ray of measured depth ``D``: band 1 the centre
    ``|z - D| < band``, 2 the tail (the rest of ``|z - D| <= T``), 0 neither; in the reference's dtype and order."""
    off = abs(z - D)
    return z < D - T, (1 if off < band else (2 if off <= T else 0))


@njit(nogil=True, cache=True)
def loss_forward(sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, sums, counts):  # pragma: no cover
    """Per ray, the five terms' squared-error sums and counts, ``sums, counts [R, 5]`` (free space, centre, tail,
    depth, colour; the first four on rays with ``rows[r] == 2``, colour on rays with ``rows[r] >= 1``).
    ``consts [2]``: the truncation ``T`` and the centre band ``0.4 T`` in the tensors' dtype."""
    one = sdf.dtype.type(1.0)
    zero = sdf.dtype.type(0.0)
    T = consts[0]
    for r in range(sdf.shape[0]):
        for k in range(5):
            sums[r, k] = zero
            counts[r, k] = 0
        if rows[r] == 0:
            continue
        c = zero
        for ch in range(3):
            err = rendered_color[r, ch] - color[r, ch]
            c += err * err
        sums[r, 4] = c
        counts[r, 4] = 3
        if rows[r] != 2:
            continue
        D = depth[r]
        for n in range(sdf.shape[1]):
            s = sdf[r, n]
            front, band = _regions(z[r, n], D, T, consts[1])
            if front:
                sums[r, 0] += (s - one) * (s - one)
                counts[r, 0] += 1
            if band:
                err = z[r, n] + s * T - D
                sums[r, band] += err * err
                counts[r, band] += 1
        err = rendered_depth[r] - D
        sums[r, 3] = err * err
        counts[r, 3] = 1


@njit(nogil=True, cache=True)
def loss_backward(sdf, z, depth, rendered_depth, rendered_color, color, rows, consts, scale, grad_sdf, grad_depth,
                  grad_color):  # pragma: no cover - compiled
    """Gradients of ``sum_k scale[k] * sums[:, k].sum()`` (``scale [5]``: each term's weight times the upstream
    gradient over its count) -> ``grad_sdf [R, N]``, ``grad_depth [R]``, ``grad_color [R, 3]``."""
    one = sdf.dtype.type(1.0)
    zero = sdf.dtype.type(0.0)
    two = sdf.dtype.type(2.0)
    T = consts[0]
    for r in range(sdf.shape[0]):
        for ch in range(3):
            grad_color[r, ch] = scale[4] * two * (rendered_color[r, ch] - color[r, ch]) if rows[r] >= 1 else zero
        if rows[r] != 2:
            grad_depth[r] = zero
            for n in range(sdf.shape[1]):
                grad_sdf[r, n] = zero
            continue
        D = depth[r]
        grad_depth[r] = scale[3] * two * (rendered_depth[r] - D)
        for n in range(sdf.shape[1]):
            s = sdf[r, n]
            front, band = _regions(z[r, n], D, T, consts[1])
            g = scale[0] * two * (s - one) if front else zero
            if band:
                g += scale[band] * two * (z[r, n] + s * T - D) * T
            grad_sdf[r, n] = g
