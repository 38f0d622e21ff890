"""The numba kernel of depth ICP's projective data association (imported lazily by :mod:`slam.core.odometry`).

The reference (``slam.core.odometry._associate_reference``) is some twenty tensor ops over the current frame's
points, each a dispatch and a pass over memory, run at every Gauss-Newton step of both pyramid levels: 0.9 ms a
step of a 33-46 ms registration at 184 x 248 (docs/benchmarks.md, "Depth ICP's association as one kernel"). Here one
pass visits each point once. The arithmetic repeats the reference's in float64 and in its order (projection,
rounding half to even, the same comparisons), and the matches come out in the reference's order, so a
registration gives the same pose bit for bit; the moved points and normals are computed by the caller, with
torch, as the reference does.

No ``fastmath``: a NaN must fail every comparison, as it does in the reference.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def associate(q, qn, vp, np_, okp, fx, fy, cx, cy, dmax, min_cos, idx, src, tgt, nrm):  # pragma: no cover - compiled
    """Projective association of moved points ``q [P, 3]`` (previous camera frame) with their moved normals
    ``qn [P, 3]`` against the previous level's points ``vp``, normals ``np_`` ``[H, W, 3]`` and validity ``okp
    [H, W]``. Writes the kept matches' point indices into ``idx [P]`` and their moved points, target points and
    target normals into ``src``, ``tgt``, ``nrm`` ``[P, 3]``, in point order; returns how many were kept."""
    H, W = okp.shape
    floor = 1e-6
    m = 0
    for i in range(q.shape[0]):
        z = q[i, 2]
        if not z > floor:
            continue
        u = np.rint(fx * q[i, 0] / z + cx)
        v = np.rint(fy * q[i, 1] / z + cy)
        if not (u >= 0.0 and u < W and v >= 0.0 and v < H):
            continue
        ui, vi = int(u), int(v)
        if not okp[vi, ui]:
            continue
        d0 = q[i, 0] - vp[vi, ui, 0]
        d1 = q[i, 1] - vp[vi, ui, 1]
        d2 = q[i, 2] - vp[vi, ui, 2]
        if not np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) < dmax:
            continue
        cos = qn[i, 0] * np_[vi, ui, 0] + qn[i, 1] * np_[vi, ui, 1] + qn[i, 2] * np_[vi, ui, 2]
        if not cos > min_cos:
            continue
        idx[m] = i
        for a in range(3):
            src[m, a] = q[i, a]
            tgt[m, a] = vp[vi, ui, a]
            nrm[m, a] = np_[vi, ui, a]
        m += 1
    return m
