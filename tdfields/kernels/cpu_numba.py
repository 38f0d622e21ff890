"""Fused multilinear interpolation for the CPU, compiled with numba (parallel over points, SIMD over channels).

Forward gathers the ``2**d`` corner rows of a channels-last grid and blends them; backward computes only the
gradients autograd asks for: the scatter into the grid (mapping) and/or the coordinate gradient (tracking).
The grid scatter runs on per-thread buffers summed at the end, so no atomics are needed.
Imported lazily by :mod:`tdfields.kernels`; the compiled code is cached on disk after the first call.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def _setup(coords, sizes, strides, n, d):
    base = 0
    w0 = w1 = w2 = 0.0
    for a in range(d):
        c = coords[n, a]
        i0 = int(np.floor(c))
        if i0 > sizes[a] - 2:
            i0 = sizes[a] - 2
        if i0 < 0:
            i0 = 0
        base += i0 * strides[a]
        if a == 0:
            w0 = c - i0
        elif a == 1:
            w1 = c - i0
        else:
            w2 = c - i0
    return base, w0, w1, w2


@njit(cache=True, inline="always")
def _corner(corner, d, strides, w0, w1, w2):
    """Offset, weight and the weight's partial derivatives (d/dw0, d/dw1, d/dw2) of one corner."""
    off = 0
    f0 = f1 = f2 = 1.0
    s0 = s1 = s2 = 0.0
    for a in range(d):
        bit = (corner >> a) & 1
        w = w0 if a == 0 else (w1 if a == 1 else w2)
        if bit:
            off += strides[a]
            f, s = w, 1.0
        else:
            f, s = 1.0 - w, -1.0
        if a == 0:
            f0, s0 = f, s
        elif a == 1:
            f1, s1 = f, s
        else:
            f2, s2 = f, s
    return off, f0 * f1 * f2, s0 * f1 * f2, f0 * s1 * f2, f0 * f1 * s2


@njit(parallel=True, fastmath=True, cache=True)
def forward(grid, sizes, strides, coords, out):
    n_points, d = coords.shape
    width = grid.shape[1]
    for n in prange(n_points):
        base, w0, w1, w2 = _setup(coords, sizes, strides, n, d)
        for f in range(width):
            out[n, f] = 0.0
        for corner in range(1 << d):
            off, wt, _, _, _ = _corner(corner, d, strides, w0, w1, w2)
            row = base + off
            for f in range(width):
                out[n, f] += wt * grid[row, f]


@njit(parallel=True, fastmath=True, cache=True)
def backward(grid, sizes, strides, coords, grad_out, grad_grid_buffers, grad_coords, want_grid, want_coords):
    n_points, d = coords.shape
    width = grid.shape[1]
    chunks = grad_grid_buffers.shape[0]
    per = (n_points + chunks - 1) // chunks
    for t in prange(chunks):
        buf = grad_grid_buffers[t]
        for n in range(t * per, min(n_points, (t + 1) * per)):
            base, w0, w1, w2 = _setup(coords, sizes, strides, n, d)
            g0 = g1 = g2 = 0.0
            for corner in range(1 << d):
                off, wt, d0, d1, d2 = _corner(corner, d, strides, w0, w1, w2)
                row = base + off
                if want_coords:
                    dot = 0.0
                    for f in range(width):
                        dot += grad_out[n, f] * grid[row, f]
                    g0 += d0 * dot
                    g1 += d1 * dot
                    g2 += d2 * dot
                if want_grid:
                    for f in range(width):
                        buf[row, f] += wt * grad_out[n, f]
            if want_coords:
                grad_coords[n, 0] = g0
                if d > 1:
                    grad_coords[n, 1] = g1
                if d > 2:
                    grad_coords[n, 2] = g2


def num_threads() -> int:
    return numba.get_num_threads()
