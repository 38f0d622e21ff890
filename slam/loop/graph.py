"""The pose graph over keyframes (gtsam): odometry edges from tracking, loop edges from verification, each weighted
by its uncertainty, optimised by Levenberg-Marquardt on SE(3).

gtsam rather than Open3D or g2o: a maintained pip wheel (Open3D's is ten times the size and pulls a renderer; g2o
has no maintained wheel), Pose3 on the manifold, and robust kernels for the loop edges."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Edge:
    """``a -> b`` keyframe positions, ``rel [4, 4]``: pose b in pose a's frame (metres), ``sigmas [6]``: standard
    deviations (rotation radians x3, translation metres x3), ``robust``: a Huber kernel (loop edges)."""

    a: int
    b: int
    rel: np.ndarray
    sigmas: np.ndarray
    robust: bool = False


def odometry_sigmas(rel: np.ndarray, trusted: bool, rot_per_m: float = 0.01, trans_per_m: float = 0.02,
                    untrusted_scale: float = 100.0) -> np.ndarray:
    """``[6]`` sigmas of an odometry edge ``rel [4, 4]``: a floor plus a share of the motion (drift grows with the
    distance and the rotation travelled), times ``untrusted_scale`` where a frame in between was not trusted by
    the tracking guard (lost, implausible): where the tracker slipped, the graph is free to move the poses."""
    from scipy.spatial.transform import Rotation

    dist = float(np.linalg.norm(rel[:3, 3]))
    ang = float(np.linalg.norm(Rotation.from_matrix(rel[:3, :3]).as_rotvec()))
    rot = 0.003 + rot_per_m * dist + 0.01 * ang
    trans = 0.005 + trans_per_m * dist + 0.005 * ang
    s = np.array([rot] * 3 + [trans] * 3)
    return s if trusted else s * untrusted_scale


def optimize(poses: np.ndarray, edges: list[Edge], iters: int = 100) -> np.ndarray:
    """Optimise keyframe poses ``[K, 4, 4]`` camera-to-world (the first held fixed) under ``edges``; returns the
    optimised ``[K, 4, 4]`` (float64)."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, T in enumerate(poses):
        values.insert(i, gtsam.Pose3(np.asarray(T, np.float64)))
    graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(np.asarray(poses[0], np.float64)),
                                     gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for e in edges:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(e.sigmas, np.float64))
        if e.robust:
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), noise)
        graph.add(gtsam.BetweenFactorPose3(e.a, e.b, gtsam.Pose3(np.asarray(e.rel, np.float64)), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iters)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.stack([result.atPose3(i).matrix() for i in range(len(poses))])
