"""World points to clamped grid coordinates for several levels at once: the fused form of
:func:`tdfields.interpolation.to_grid_coords`, hand-written numba (imported lazily by
:mod:`tdfields.kernels.numba.autograd`, needs numba).

The reference builds the coordinates from a dozen broadcast ops on ``[N, 3]`` tensors, and their backward
(``minimum``/``maximum`` tie handling) adds as many again: 5.6 ms of a 58 ms tracking iteration at room0 scale
(two 2-level fields, 80k points), most of it TensorIterator overhead on a size-3 inner dimension. Here one pass
writes every level's coordinates and one pass reduces the gradient. The arithmetic repeats the reference's
operation by operation (``(p - lo) / extent * (n - 1)``, then the clamp, ties in the clamp passing half the
gradient, as ``torch.maximum``/``torch.minimum`` do), so values agree bit for bit.

No ``fastmath``: a NaN point must stay NaN through the clamp, as it does in the reference.
"""

from __future__ import annotations

from numba import njit


@njit(nogil=True, cache=True)
def grid_coords_forward(points, lo, extent, top, out, start, stop):  # pragma: no cover - compiled
    """``points [N, 3]``, per level ``lo, extent, top [L, 3]`` (``top = n - 1``) -> ``out [L, N, 3]``."""
    zero = points.dtype.type(0.0)
    for level in range(lo.shape[0]):
        for n in range(start, stop):
            for a in range(3):
                g = (points[n, a] - lo[level, a]) / extent[level, a] * top[level, a]
                if g < zero:
                    g = zero
                if g > top[level, a]:
                    g = top[level, a]
                out[level, n, a] = g


@njit(nogil=True, cache=True)
def grid_coords_backward(points, lo, extent, top, grad, out, start, stop):  # pragma: no cover - compiled
    """``grad [L, N, 3]`` w.r.t. the coordinates -> ``out [N, 3]`` w.r.t. the points."""
    zero = points.dtype.type(0.0)
    half = points.dtype.type(0.5)
    one = points.dtype.type(1.0)
    for n in range(start, stop):
        for a in range(3):
            s = zero
            for level in range(lo.shape[0]):
                g = (points[n, a] - lo[level, a]) / extent[level, a] * top[level, a]
                # maximum(g, 0) then minimum(., top): 1 inside, 1/2 at a tie, 0 where clamped
                f = one if g > zero else (half if g == zero else zero)
                m = g if g > zero else zero
                f *= one if m < top[level, a] else (half if m == top[level, a] else zero)
                s += grad[level, n, a] * f * top[level, a] / extent[level, a]
            out[n, a] = s
