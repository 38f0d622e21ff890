"""The camera path: a hand-held-like loop around the room centre at 30 Hz.

Radius ``path_radius`` (~0.9 m), looking inward and slightly down, with slow sinusoidal wobble in position, yaw,
pitch and roll (about 1.4 cm and about 1 degree per frame; ``loop_frames`` frames close the loop).
"""

from __future__ import annotations

import numpy as np

from slam.data.synthetic.config import SynthConfig


def camera_path(cfg: SynthConfig) -> np.ndarray:
    """``[frames, 4, 4]`` camera-to-world poses (OpenCV axes) of the hand-held-like loop."""
    rng = np.random.default_rng([cfg.seed, 1])
    ph = rng.uniform(0, 2 * np.pi, 8)
    k = np.arange(cfg.frames, dtype=np.float64)
    th = -np.pi / 2 + 2 * np.pi * k / cfg.loop_frames
    r = cfg.path_radius + 0.06 * np.sin(2 * th + ph[0])
    x = r * np.cos(th) + 0.015 * np.sin(k * 2 * np.pi / 47 + ph[1])
    y = r * np.sin(th) + 0.015 * np.sin(k * 2 * np.pi / 53 + ph[2])
    z = 1.35 + 0.08 * np.sin(3 * th + ph[3]) + 0.01 * np.sin(k * 2 * np.pi / 41 + ph[4])
    yaw = th + np.pi + 0.30 * np.sin(2 * th + ph[5])
    pitch = -0.32 + 0.07 * np.sin(3.7 * th + ph[6])
    roll = 0.04 * np.sin(5 * th + ph[7])
    return look_poses(np.stack([x, y, z], 1), yaw, pitch, roll)


def look_poses(pos: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """``[N, 4, 4]`` camera-to-world poses (OpenCV axes) at ``pos [N, 3]`` looking along ``yaw`` (radians about
    world z, from +x), ``pitch`` (up positive) and ``roll`` about the optical axis, with world z up."""
    poses = np.tile(np.eye(4), (len(pos), 1, 1))
    fwd = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], 1)
    right = np.cross(fwd, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(fwd, right)
    cr, sr = np.cos(roll)[:, None], np.sin(roll)[:, None]
    poses[:, :3, 0] = cr * right + sr * down
    poses[:, :3, 1] = -sr * right + cr * down
    poses[:, :3, 2] = fwd
    poses[:, :3, 3] = pos
    return poses
