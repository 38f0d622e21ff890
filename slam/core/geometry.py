"""Rigid camera poses as numpy ``[N, 4, 4]`` camera-to-world matrices: the rigidity check and the TUM row form.

Both the loaders (:mod:`slam.data`, which check every ground-truth pose they read and parse TUM ground truth) and
the evaluation (:mod:`slam.eval`, which reads and writes TUM trajectories) need these, so they live below both.
Float64, metres, OpenCV camera axes as everywhere in :mod:`slam`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from slam.errors import SlamInputError

__all__ = ["check_rigid", "poses_from_tum", "poses_to_tum"]


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
