"""Pairing by timestamp, shared by the loaders that pair streams themselves (TUM folders, ROS bags): the nearest
sample of a sorted stream, ground truth at given times, and the spacing of kept frames."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from slam.core.geometry import poses_from_tum

__all__ = ["nearest", "poses_at", "spaced"]


def nearest(sorted_ts: np.ndarray, query: np.ndarray) -> np.ndarray:
    """For each ``query [M]`` time (seconds) the index of the nearest of ``sorted_ts [N]`` (N >= 2, ascending);
    a tie goes to the earlier sample."""
    j = np.clip(np.searchsorted(sorted_ts, query), 1, len(sorted_ts) - 1)
    left = sorted_ts[j - 1]
    right = sorted_ts[j]
    return np.where(np.abs(query - left) <= np.abs(right - query), j - 1, j)


def poses_at(gt_ts: np.ndarray, gt_rows: np.ndarray, query: np.ndarray, max_dt: float, interpolate: bool):
    """Poses ``[M, 4, 4]`` at ``query [M]`` times and a ``[M]`` mask of times with ground truth within ``max_dt``.

    ``gt_ts [N]`` ascending seconds, ``gt_rows [N, 7]`` TUM rows ``tx ty tz qx qy qz qw``. With ``interpolate``
    a time with samples on both sides within ``max_dt`` gets them interpolated (linear position, slerp rotation),
    else the nearest sample."""
    near = nearest(gt_ts, query) if len(gt_ts) > 1 else np.zeros(len(query), dtype=np.int64)
    ok = np.abs(gt_ts[near] - query) < max_dt
    poses = poses_from_tum(gt_rows[near])
    if interpolate and len(gt_ts) > 1:
        j = np.searchsorted(gt_ts, query, side="right")
        inner = (j > 0) & (j < len(gt_ts))
        jj = np.clip(j, 1, len(gt_ts) - 1)
        t0, t1 = gt_ts[jj - 1], gt_ts[jj]
        inner &= (query - t0 < max_dt) & (t1 - query < max_dt) & (t1 > t0)
        if inner.any():
            k = np.flatnonzero(inner)
            a = ((query[k] - t0[k]) / (t1[k] - t0[k]))[:, None]
            pos = (1 - a) * gt_rows[jj[k] - 1, :3] + a * gt_rows[jj[k], :3]
            rots = []
            for kk, aa in zip(k, a[:, 0]):
                key = Rotation.from_quat(gt_rows[[jj[kk] - 1, jj[kk]], 3:7])
                rots.append(Slerp([0.0, 1.0], key)([aa]).as_matrix()[0])
            poses[k, :3, :3] = np.stack(rots)
            poses[k, :3, 3] = pos
            ok |= inner
    return poses, ok


def spaced(ts: np.ndarray, keep: np.ndarray, min_dt: float) -> np.ndarray:
    """``keep [N]`` without the frames closer than ``min_dt`` seconds to the previous kept one."""
    keep = keep.copy()
    last = -np.inf
    for k in range(len(ts)):
        if keep[k]:
            if ts[k] - last < min_dt:
                keep[k] = False
            else:
                last = ts[k]
    return keep
