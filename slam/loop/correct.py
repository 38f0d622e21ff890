"""The pose graph's correction carried to every frame: each frame moves with the keyframes around it, the
correction interpolated between them (slerp for the rotation) by the frame's position in the sequence."""

from __future__ import annotations

import numpy as np


def correct_frames(poses: np.ndarray, key_positions: list[int], before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Frames' camera-to-world ``poses [N, 4, 4]`` moved with their keyframes.

    Args:
        key_positions: the keyframes' frame positions, increasing; before/after: their poses ``[K, 4, 4]`` before
            and after the optimisation.

    Returns:
        ``[N, 4, 4]``: ``C(k) @ poses[k]``, with ``C = after @ before^-1`` at each keyframe, interpolated between
        keyframes, held before the first and after the last.
    """
    from scipy.spatial.transform import Rotation, Slerp

    poses = np.asarray(poses, np.float64)
    if not len(key_positions):
        return poses.copy()
    C = np.asarray(after, np.float64) @ np.linalg.inv(np.asarray(before, np.float64))
    keys = np.asarray(key_positions, np.float64)
    k = np.clip(np.arange(len(poses), dtype=np.float64), keys[0], keys[-1])
    if len(keys) == 1:
        rot = Rotation.from_matrix(np.repeat(C[:1, :3, :3], len(poses), 0))
        trans = np.repeat(C[:1, :3, 3], len(poses), 0)
    else:
        rot = Slerp(keys, Rotation.from_matrix(C[:, :3, :3]))(k)
        trans = np.stack([np.interp(k, keys, C[:, i, 3]) for i in range(3)], 1)
    out = poses.copy()
    R = rot.as_matrix()
    out[:, :3, :3] = R @ poses[:, :3, :3]
    out[:, :3, 3] = (R @ poses[:, :3, 3, None])[..., 0] + trans
    return out
