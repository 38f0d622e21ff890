"""Trajectory I/O in the TUM text format, pose conversions and timestamp association.

TUM format: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (camera-to-world, metres, Hamilton
quaternion with the real part last), ``#`` starts a comment. ``evo`` and the TUM benchmark tools read and
write exactly this, so trajectories written here can be checked with them and vice versa.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from slam.errors import SlamInputError

__all__ = [
    "read_tum_trajectory",
    "write_tum_trajectory",
    "associate",
    "poses_from_tum",
    "poses_to_tum",
    "check_rigid",
]


def poses_from_tum(rows: np.ndarray) -> np.ndarray:
    """Convert ``[N, 7]`` rows ``tx ty tz qx qy qz qw`` to ``[N, 4, 4]`` float64 matrices.

    Quaternions are normalised first (TUM files carry 4 decimals, so ``|q|`` is only ~1).
    """
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    if len(rows):
        poses[:, :3, :3] = Rotation.from_quat(rows[:, 3:7]).as_matrix()
        poses[:, :3, 3] = rows[:, :3]
    return poses


def poses_to_tum(poses: np.ndarray) -> np.ndarray:
    """Convert ``[N, 4, 4]`` rigid matrices to ``[N, 7]`` rows ``tx ty tz qx qy qz qw`` (``qw >= 0``)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat() if len(poses) else np.zeros((0, 4))
    q = np.where(q[:, 3:4] < 0, -q, q)  # one canonical sign so files diff cleanly
    return np.concatenate([poses[:, :3, 3], q], axis=1)


def check_rigid(poses: np.ndarray, source: str, tol: float = 1e-3, allow_nan: bool = False) -> np.ndarray:
    """Raise :class:`SlamInputError` naming ``source`` unless every ``[N, 4, 4]`` pose is a rigid transform.

    A pose is rigid when ``R^T R = I`` and ``det R = 1`` within ``tol`` and the last row is ``0 0 0 1``.
    With ``allow_nan`` a pose that is entirely non-finite (ScanNet's marker for a lost GT pose) is accepted.
    Returns the boolean ``[N]`` mask of valid (finite) poses.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    finite = np.isfinite(poses).all(axis=(1, 2))
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        if not allow_nan:
            raise SlamInputError(f"{source}: pose {bad} contains NaN or inf")
    good = poses[finite]
    if len(good):
        r = good[:, :3, :3]
        ortho = np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(r)
        last = np.abs(good[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
        bad_mask = (ortho > tol) | (np.abs(det - 1.0) > tol) | (last > tol)
        if bad_mask.any():
            bad = int(np.flatnonzero(finite)[np.flatnonzero(bad_mask)[0]])
            raise SlamInputError(
                f"{source}: pose {bad} is not a rigid transform (|R^T R - I| = {ortho[bad_mask][0]:.3g}, "
                f"det R = {det[bad_mask][0]:.4f})"
            )
    return finite


def _read_rows(path: Path, min_cols: int) -> list[list[str]]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SlamInputError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SlamInputError(f"{path}: cannot read ({exc})") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < min_cols:
            raise SlamInputError(f"{path}:{lineno}: expected {min_cols} columns, got {len(parts)}")
        rows.append(parts)
    return rows


def read_tum_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory file.

    Returns ``(timestamps [N] float64 seconds, poses [N, 4, 4] float64 camera-to-world)``, in file order.
    Raises :class:`SlamInputError` for a missing file, a malformed line, an empty trajectory, NaN values or a
    quaternion far from unit length (a sign of a wrong column order).
    """
    path = Path(path)
    rows = _read_rows(path, 8)
    if not rows:
        raise SlamInputError(f"{path}: no poses (empty trajectory)")
    try:
        data = np.array([[float(v) for v in r[:8]] for r in rows], dtype=np.float64)
    except ValueError as exc:
        raise SlamInputError(f"{path}: non-numeric value ({exc})") from None
    if not np.isfinite(data).all():
        bad = int(np.flatnonzero(~np.isfinite(data).all(axis=1))[0])
        raise SlamInputError(f"{path}: pose {bad} (timestamp {data[bad, 0]:.6f}) contains NaN or inf")
    qn = np.linalg.norm(data[:, 4:8], axis=1)
    if np.any(np.abs(qn - 1.0) > 0.01):
        bad = int(np.flatnonzero(np.abs(qn - 1.0) > 0.01)[0])
        raise SlamInputError(
            f"{path}: pose {bad} has quaternion norm {qn[bad]:.4f}; expected unit quaternions in the TUM "
            "column order 'timestamp tx ty tz qx qy qz qw'"
        )
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


def rotation_angle_deg(r: np.ndarray) -> np.ndarray:
    """Rotation angle in degrees of ``[..., 3, 3]`` rotation matrices."""
    tr = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(tr))

