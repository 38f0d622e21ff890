"""Trajectory I/O in the TUM text format, pose conversions and timestamp association.

TUM format: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (camera-to-world, metres, Hamilton
quaternion with the real part last), ``#`` starts a comment. ``evo`` and the TUM benchmark tools read and
write exactly this, so trajectories written here can be checked with them and vice versa. The row conversions
and the rigidity check live in :mod:`slam.core.geometry` (the loaders use them too) and are re-exported here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slam.errors import SlamInputError
from slam.core.geometry import check_rigid, poses_from_tum, poses_to_tum
from slam.core.pose import pose_gap
from slam.data.tum_format import read_tum_poses

__all__ = [
    "read_tum_trajectory",
    "write_tum_trajectory",
    "associate",
    "poses_from_tum",
    "poses_to_tum",
    "check_rigid",
    "frame_steps",
]


def read_tum_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory file.

    Returns ``(timestamps [N] float64 seconds, poses [N, 4, 4] float64 camera-to-world)``, in file order.
    Raises :class:`SlamInputError` for a missing file, a malformed line, an empty trajectory, NaN values or a
    quaternion far from unit length (a sign of a wrong column order): :func:`slam.data.tum_format.read_tum_poses`,
    the one reader of the format, which the TUM loader's ground truth goes through too.
    """
    data = read_tum_poses(path)
    return data[:, 0], poses_from_tum(data[:, 1:8])


def write_tum_trajectory(path: str | Path, timestamps, poses) -> Path:
    """Write ``timestamps [N]`` (seconds) and ``poses [N, 4, 4]`` (camera-to-world) as a TUM trajectory.

    Accepts numpy arrays or torch tensors. Non-finite poses are skipped (the TUM format cannot hold them).
    Raises :class:`SlamInputError` if the lengths differ or a finite pose is not rigid.
    """
    path = Path(path)
    ts = np.asarray(_to_numpy(timestamps), dtype=np.float64).reshape(-1)
    poses = np.asarray(_to_numpy(poses), dtype=np.float64).reshape(-1, 4, 4)
    if len(ts) != len(poses):
        raise SlamInputError(f"{path}: {len(ts)} timestamps but {len(poses)} poses")
    finite = check_rigid(poses, str(path), tol=1e-3, allow_nan=True)
    rows = poses_to_tum(poses[finite])
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, r in zip(ts[finite], rows):
            fh.write(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in r) + "\n")
    return path


def associate(ts_a, ts_b, max_dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Pair two timestamp lists as TUM's ``associate.py`` does.

    Every pair with ``|a - b| < max_dt`` (seconds) is a candidate; candidates are taken greedily by increasing
    time difference, each timestamp used at most once. Returns index arrays ``(ia [M], ib [M])`` sorted by
    ``ia``. ``M`` may be 0; callers decide whether that is an error.
    """
    a = np.asarray(ts_a, dtype=np.float64).reshape(-1)
    b = np.asarray(ts_b, dtype=np.float64).reshape(-1)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.argsort(b, kind="stable")
    bs = b[order]
    lo = np.searchsorted(bs, a - max_dt, side="left")
    hi = np.searchsorted(bs, a + max_dt, side="right")
    ia_list, ib_list = [], []
    for i in range(len(a)):
        if hi[i] > lo[i]:
            ia_list.append(np.full(hi[i] - lo[i], i))
            ib_list.append(order[lo[i]:hi[i]])
    if not ia_list:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    ia = np.concatenate(ia_list)
    ib = np.concatenate(ib_list)
    diff = np.abs(a[ia] - b[ib])
    keep = diff < max_dt
    ia, ib, diff = ia[keep], ib[keep], diff[keep]
    used_a = np.zeros(len(a), bool)
    used_b = np.zeros(len(b), bool)
    out_a, out_b = [], []
    for k in np.argsort(diff, kind="stable"):
        if not used_a[ia[k]] and not used_b[ib[k]]:
            used_a[ia[k]] = used_b[ib[k]] = True
            out_a.append(ia[k])
            out_b.append(ib[k])
    out_a = np.asarray(out_a, dtype=np.int64)
    out_b = np.asarray(out_b, dtype=np.int64)
    srt = np.argsort(out_a, kind="stable")
    return out_a[srt], out_b[srt]


def _to_numpy(x):
    if hasattr(x, "detach"):
        return x.detach().cpu().numpy()
    return x


def frame_steps(poses) -> dict | None:
    """How far apart consecutive poses are: the turn (degrees) and the move (centimetres) from each pose to the next
    of ``poses`` ``[N, 4, 4]`` camera-to-world (metres), as ``{"turn_deg": {...}, "move_cm": {...}}`` with the
    ``median``, ``p95`` and ``max`` of each; None without two consecutive finite poses. A step needs both of its poses
    finite: the two poses either side of a non-finite one are two steps apart, not one. A run's tracker starts each
    frame from depth ICP against the one before, and how far apart they are bounds how well it does
    (docs/robustness.md, "How far apart the frames can be")."""
    T = np.asarray(_to_numpy(poses), dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"frame_steps: poses must be [N, 4, 4], got {tuple(T.shape)}")
    finite = np.isfinite(T).all(axis=(1, 2))
    pairs = np.flatnonzero(finite[:-1] & finite[1:])
    if len(pairs) == 0:
        return None
    gaps = np.array([pose_gap(T[i], T[i + 1]) for i in pairs])  # (metres, degrees) from each pose to the next
    out = {}
    for name, vals in (("turn_deg", gaps[:, 1]), ("move_cm", 100.0 * gaps[:, 0])):
        out[name] = {"median": round(float(np.median(vals)), 3), "p95": round(float(np.percentile(vals, 95)), 3),
                     "max": round(float(vals.max()), 3)}
    return out
