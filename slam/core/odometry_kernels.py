"""Depth ICP's registration as numba kernels (imported lazily by :mod:`slam.core.odometry`, the default of
``icp_relative_pose``; ``kernel=False`` runs the tensor-op reference there).

:func:`register` runs the pyramid: each level's points and normals in one pass (:func:`level_points`) and the
level's Gauss-Newton steps in one call (:func:`register_level`: move the points, associate them
(:func:`associate`), Huber-weighted point-to-plane normal equations, a 6x6 solve, the twist's exponential). The
tensor-op reference spent about 1 ms a step in some forty dispatches around the association (measured at
commit f5975fa: ``git show f5975fa:docs/benchmarks.md``, section "Depth ICP as kernels").

The association repeats the reference's arithmetic (``slam.core.odometry._associate``) in float64 and in its order
(projection, rounding half to even, the same comparisons), and its matches come out in the reference's order: the
same matches, bit for bit, for the same moved points. The rest is the reference's formulas in float64; its sums of
products (the moved points, the normal equations) run in another order than the reference's BLAS calls, so a pose
can differ from the reference's in the last bits of a double, below the float32 the pose is handed on in
(``tests/slam/core/test_odometry.py``).

No ``fastmath``: a NaN must fail every comparison, as it does in the reference.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def associate(q, qn, vp, np_, okp, fx, fy, cx, cy, dmax, pmax, min_cos, idx, src, tgt, nrm):  # pragma: no cover - compiled
    """Projective association of moved points ``q [P, 3]`` (previous camera frame) with their moved normals
    ``qn [P, 3]`` against the previous level's points ``vp``, normals ``np_`` ``[H, W, 3]`` and validity ``okp
    [H, W]``, kept where the point-to-plane distance is below ``dmax``, the points' distance below ``pmax`` and
    the normals' cosine above ``min_cos``. Writes the kept matches' point indices into ``idx [P]`` and their moved
    points, target points and target normals into ``src``, ``tgt``, ``nrm`` ``[P, 3]``, in point order; returns how
    many were kept."""
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
        if not np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) < pmax:
            continue
        if not abs(d0 * np_[vi, ui, 0] + d1 * np_[vi, ui, 1] + d2 * np_[vi, ui, 2]) < dmax:
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


@njit(nogil=True, cache=True)
def level_points(depth, fx, fy, cx, cy, max_jump, vert, nrm, ok):  # pragma: no cover - compiled
    """One pyramid level's camera-frame points ``vert``, unit normals ``nrm`` ``[H, W, 3]`` and their validity
    ``ok [H, W]`` (written) of ``depth [H, W]`` (float64 metres): ``odometry._level_points``' formulas (backprojection,
    central differences, the four-neighbour depth and jump checks, normals facing the camera), 0 / False on the
    border."""
    H, W = depth.shape
    for i in range(H):
        for j in range(W):
            z = depth[i, j]
            vert[i, j, 0] = (j - cx) / fx * z
            vert[i, j, 1] = (i - cy) / fy * z
            vert[i, j, 2] = z
            nrm[i, j, 0] = 0.0
            nrm[i, j, 1] = 0.0
            nrm[i, j, 2] = 0.0
            ok[i, j] = False
    for i in range(1, H - 1):
        for j in range(1, W - 1):
            dx0 = vert[i, j + 1, 0] - vert[i, j - 1, 0]
            dx1 = vert[i, j + 1, 1] - vert[i, j - 1, 1]
            dx2 = vert[i, j + 1, 2] - vert[i, j - 1, 2]
            dy0 = vert[i + 1, j, 0] - vert[i - 1, j, 0]
            dy1 = vert[i + 1, j, 1] - vert[i - 1, j, 1]
            dy2 = vert[i + 1, j, 2] - vert[i - 1, j, 2]
            c0 = dx1 * dy2 - dx2 * dy1
            c1 = dx2 * dy0 - dx0 * dy2
            c2 = dx0 * dy1 - dx1 * dy0
            norm = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            d = depth[i, j]
            jump = max_jump * d
            good = d > 0.0 and norm > 1e-12
            for n in (depth[i, j + 1], depth[i, j - 1], depth[i + 1, j], depth[i - 1, j]):
                good = good and n > 0.0 and abs(n - d) < jump
            nn = norm if norm > 1e-12 else 1e-12
            nrm[i, j, 0] = -c0 / nn  # facing the camera: dx x dy points away for y-down images
            nrm[i, j, 1] = -c1 / nn
            nrm[i, j, 2] = -c2 / nn
            ok[i, j] = good


@njit(nogil=True, cache=True)
def smooth_normals(nrm, ok, k, out, out_ok):  # pragma: no cover - compiled
    """``odometry.smooth_normals``: the valid normals of ``nrm [H, W, 3]`` (``ok [H, W]``) summed over ``k`` pixels
    square, made unit, into ``out``; ``out_ok`` valid before with more than half of the ``k * k`` square valid (the
    image's outside counting as invalid)."""
    H, W = ok.shape
    h = k // 2
    for i in range(H):
        for j in range(W):
            s0, s1, s2, c = 0.0, 0.0, 0.0, 0
            for ii in range(max(i - h, 0), min(i + h + 1, H)):
                for jj in range(max(j - h, 0), min(j + h + 1, W)):
                    if ok[ii, jj]:
                        s0 += nrm[ii, jj, 0]
                        s1 += nrm[ii, jj, 1]
                        s2 += nrm[ii, jj, 2]
                        c += 1
            norm = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            norm = norm if norm > 1e-12 else 1e-12
            out[i, j, 0], out[i, j, 1], out[i, j, 2] = s0 / norm, s1 / norm, s2 / norm
            out_ok[i, j] = ok[i, j] and c / (k * k) > 0.5


@njit(nogil=True, cache=True)
def _solve6(A, b):  # pragma: no cover - compiled
    """``A^-1 b`` of a 6x6 system by Gaussian elimination with partial pivoting (A and b are overwritten)."""
    n = 6
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if p != c:
            for k in range(n):
                A[c, k], A[p, k] = A[p, k], A[c, k]
            b[c], b[p] = b[p], b[c]
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            for k in range(c, n):
                A[r, k] -= f * A[c, k]
            b[r] -= f * b[c]
    x = np.zeros(n)
    for c in range(n - 1, -1, -1):
        s = b[c]
        for k in range(c + 1, n):
            s -= A[c, k] * x[k]
        x[c] = s / A[c, c]
    return x


@njit(nogil=True, cache=True)
def _left_multiply_exp(xi, T):  # pragma: no cover - compiled
    """``T <- exp_se3(xi) @ T`` in place, ``slam.core.pose.exp_se3``'s formula (exact rotation, first-order
    translation)."""
    w0, w1, w2 = xi[0], xi[1], xi[2]
    theta = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2], K[1, 0], K[1, 2], K[2, 0], K[2, 1] = -w2, w1, w2, -w0, -w1, w0
    E = np.eye(4)
    if theta < 1e-12:
        for i in range(3):
            for j in range(3):
                E[i, j] += K[i, j]
    else:
        a = np.sin(theta) / theta
        b = (1.0 - np.cos(theta)) / theta ** 2
        KK = K @ K
        for i in range(3):
            for j in range(3):
                E[i, j] = (E[i, j] + a * K[i, j]) + b * KK[i, j]
    E[0, 3], E[1, 3], E[2, 3] = xi[3], xi[4], xi[5]
    T[:, :] = E @ T


@njit(nogil=True, cache=True)
def register_level(pts, pnrm, vp, np_, okp, T, fx, fy, cx, cy, dmax, pmax, min_cos, n_it, out):  # pragma: no cover
    """Up to ``n_it`` robust Gauss-Newton steps of one pyramid level: the current frame's points ``pts`` and
    normals ``pnrm`` ``[P, 3]`` moved by ``T [4, 4]`` (float64, updated in place) onto the previous frame's
    ``vp``, ``np_``, ``okp`` (:func:`level_points`), as ``odometry.icp_relative_pose``'s inner loop: associate, the
    point-to-plane residuals with Huber weights (scale 1.4826 x their lower median), ``(A + 1e-6 I) xi = b``,
    ``T <- exp(xi) T``, done once ``|xi| < 1e-5``.

    ``out`` ``[2]``: the last step's inlier share (matches / P) and RMS residual (metres), left as given when no step
    ran. Returns True when a step found fewer than 50 matches (``T`` as before that step; ``out[0]`` its share)."""
    P = pts.shape[0]
    q = np.empty((P, 3))
    qn = np.empty((P, 3))
    idx = np.empty(P, dtype=np.int64)
    src = np.empty((P, 3))
    tgt = np.empty((P, 3))
    nrm = np.empty((P, 3))
    r = np.empty(P)
    absr = np.empty(P)
    J = np.empty(6)
    for _ in range(n_it):
        for i in range(P):
            for a in range(3):
                q[i, a] = pts[i, 0] * T[a, 0] + pts[i, 1] * T[a, 1] + pts[i, 2] * T[a, 2] + T[a, 3]
                qn[i, a] = pnrm[i, 0] * T[a, 0] + pnrm[i, 1] * T[a, 1] + pnrm[i, 2] * T[a, 2]
        m = associate(q, qn, vp, np_, okp, fx, fy, cx, cy, dmax, pmax, min_cos, idx, src, tgt, nrm)
        if m < 50:
            out[0] = m / max(P, 1)
            return True
        for k in range(m):
            r[k] = ((src[k, 0] - tgt[k, 0]) * nrm[k, 0] + (src[k, 1] - tgt[k, 1]) * nrm[k, 1]
                    + (src[k, 2] - tgt[k, 2]) * nrm[k, 2])
            absr[k] = abs(r[k])
        half = (m - 1) // 2  # the lower median, as torch.median
        med = np.partition(absr[:m], half)[half]
        scale = 1.4826 * (med if med > 1e-4 else 1e-4)
        A = np.zeros((6, 6))
        b = np.zeros(6)
        ss = 0.0
        for k in range(m):
            s0, s1, s2 = src[k, 0], src[k, 1], src[k, 2]
            n0, n1, n2 = nrm[k, 0], nrm[k, 1], nrm[k, 2]
            J[0], J[1], J[2] = s1 * n2 - s2 * n1, s2 * n0 - s0 * n2, s0 * n1 - s1 * n0  # d r / d (w, t), left twist
            J[3], J[4], J[5] = n0, n1, n2
            h = absr[k] / (1.345 * scale)
            w = 1.0 / (h if h > 1.0 else 1.0)
            for a in range(6):
                wa = w * J[a]
                b[a] -= wa * r[k]
                for c in range(6):
                    A[a, c] += wa * J[c]
            ss += r[k] * r[k]
        for a in range(6):
            A[a, a] += 1e-6
        xi = _solve6(A, b)
        _left_multiply_exp(xi, T)
        out[0] = m / P
        out[1] = np.sqrt(ss / m)
        if np.sqrt(np.sum(xi * xi)) < 1e-5:  # a NaN step goes on, as in the reference
            break
    return False


def register(depth_prev, depth_cur, T, cam, levels, iters, max_dist, point_gate, min_cos, max_jump, smooth=1):
    """``odometry.icp_relative_pose``'s loop over the pyramid on numpy float64 arrays: depths ``[H, W]``, ``T``
    ``[4, 4]`` the start (updated in place), ``cam`` the full image's ``(fx, fy, cx, cy)``, ``smooth`` the normals'
    averaging square (:func:`smooth_normals`; 1: none), ``point_gate`` times a level's ``max_dist`` the largest
    distance between a match's points. Returns ``(inliers, rmse, failed)``: the last step's inlier share and RMS residual, and whether a level had too few points or matches
    (the caller's failure result, ``T`` where it stopped)."""
    fx, fy, cx, cy = cam
    out = np.array([0.0, np.inf])
    for f, n_it, dmax in zip(levels, iters, max_dist):
        lcam = (fx / f, fy / f, cx / f, cy / f)  # pixel (u, v) of the level sits at (f u, f v) of the full image
        prev, cur = [], []
        for d, keep in ((depth_prev, prev), (depth_cur, cur)):
            d = np.ascontiguousarray(d[::f, ::f])
            v, n, ok = np.empty(d.shape + (3,)), np.empty(d.shape + (3,)), np.empty(d.shape, dtype=np.bool_)
            level_points(d, *lcam, max_jump, v, n, ok)
            if smooth > 1:
                n_raw, ok_raw = n, ok
                n, ok = np.empty_like(n_raw), np.empty_like(ok_raw)
                smooth_normals(n_raw, ok_raw, smooth, n, ok)
            keep += [v, n, ok]
        pts, pnrm = cur[0][cur[2]], cur[1][cur[2]]  # [P, 3] current camera frame, row-major as the reference
        if pts.shape[0] < 50 or int(prev[2].sum()) < 50:
            return 0.0, np.inf, True
        if register_level(pts, pnrm, prev[0], prev[1], prev[2], T, *lcam, dmax, point_gate * dmax, min_cos, n_it,
                          out):
            return float(out[0]), np.inf, True
    return float(out[0]), float(out[1]), False
