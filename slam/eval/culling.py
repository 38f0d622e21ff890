"""Frustum and occlusion culling of meshes (ESLAM ``cull_mesh``): remove what no camera saw."""

from __future__ import annotations

from typing import Iterable

import numpy as np

from slam.errors import SlamInputError

__all__ = ["cull_mesh", "visible_vertices"]


def _np(x):
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _bilinear(depth: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    h, w = depth.shape
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    u0 = np.clip(np.floor(u).astype(np.int64), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, h - 2)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * depth[v0, u0] + a * (1 - b) * depth[v0, u0 + 1]
            + (1 - a) * b * depth[v0 + 1, u0] + a * b * depth[v0 + 1, u0 + 1])


def visible_vertices(vertices, poses, intrinsics, depths: Iterable | None = None, truncation: float = 0.06) -> np.ndarray:
    """``[V]`` bool: vertex seen by at least one camera.

    Args:
        vertices: ``[V, 3]`` world points (metres).
        poses: ``[N, 4, 4]`` camera-to-world, OpenCV axes; non-finite poses are skipped.
        intrinsics: :class:`slam.data.Intrinsics` of the image the vertices are projected into.
        depths: optional iterable of ``N`` depth maps ``[H, W]`` (metres, 0 invalid; numpy or torch, may be a
            generator); a None entry culls that frame by its frustum only (its depth could not be read). With depths a vertex also needs ``z <= D(u, v) + truncation`` (bilinear D): it may be
            hidden by at most ``truncation`` metres.
        truncation: occlusion tolerance in metres (the TSDF truncation, 6 cm).

    A vertex is in a frame if it is in front of the camera and strictly inside the image
    (``0 < u < W``, ``0 < v < H``), the reference rule.
    """
    v = _np(vertices).reshape(-1, 3)
    poses = _np(poses).reshape(-1, 4, 4)
    k = intrinsics
    seen = np.zeros(len(v), dtype=bool)
    depth_iter = iter(depths) if depths is not None else None
    for i, pose in enumerate(poses):
        depth = None
        if depth_iter is not None:
            try:
                depth = next(depth_iter)
            except StopIteration:
                raise SlamInputError(f"cull_mesh: {len(poses)} poses but only {i} depth maps") from None
            depth = None if depth is None else _np(depth)  # None: that frame's depth is unreadable, frustum only
            if depth is not None and depth.shape != (k.height, k.width):
                raise SlamInputError(f"cull_mesh: depth map {i} is {depth.shape}, intrinsics say {(k.height, k.width)}")
        if not np.isfinite(pose).all():
            continue
        for s in range(0, len(v), CHUNK):  # a chunk at a time: the temporaries stay small for a large mesh
            seen[s:s + CHUNK] |= _in_view(v[s:s + CHUNK], pose, k, depth, truncation)
    return seen


#: vertices projected at a time by :func:`visible_vertices`
CHUNK = 1 << 18


def _in_view(v: np.ndarray, pose: np.ndarray, k, depth: np.ndarray | None, truncation: float) -> np.ndarray:
    """``[V]`` bool: the rule of :func:`visible_vertices` for the vertices ``v [V, 3]`` in one frame."""
    p = (v - pose[:3, 3]) @ pose[:3, :3]
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k.fx * p[:, 0] / z + k.cx
        vv = k.fy * p[:, 1] / z + k.cy
    m = (z > 0) & (u > 0) & (u < k.width) & (vv > 0) & (vv < k.height)
    if depth is not None and m.any():
        idx = np.flatnonzero(m)
        d = _bilinear(depth, u[idx], vv[idx])
        m[idx] = d + truncation >= z[idx]
    return m


def cull_mesh(mesh, poses, intrinsics, depths: Iterable | None = None, truncation: float = 0.06):
    """Copy of ``mesh`` without the faces whose three vertices no camera saw (see :func:`visible_vertices`),
    unreferenced vertices removed. ``mesh`` is a Trimesh or a path; returns a ``trimesh.Trimesh``."""
    from slam.eval.mesh_metrics import load_mesh

    m = load_mesh(mesh, "mesh").copy()
    seen = visible_vertices(m.vertices, poses, intrinsics, depths, truncation)
    keep = seen[m.faces].any(axis=1)
    m.update_faces(keep)
    m.remove_unreferenced_vertices()
    return m
