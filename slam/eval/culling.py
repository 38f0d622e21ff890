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


def visible_vertices(vertices, poses, intrinsics, depths: Iterable | None = None, truncation: float = 0.06,
                     groups: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``[V]`` bool: vertex seen by at least one camera.

    Args:
        vertices: ``[V, 3]`` world points (metres).
        poses: ``[N, 4, 4]`` camera-to-world, OpenCV axes; non-finite poses are skipped.
        intrinsics: :class:`slam.data.Intrinsics` of the image the vertices are projected into.
        depths: optional iterable of ``N`` depth maps ``[H, W]`` (metres, 0 invalid; numpy or torch, may be a
            generator); a None entry culls that frame by its frustum only (its depth could not be read). With depths a vertex also needs ``z <= D(u, v) + truncation`` (bilinear D): it may be
            hidden by at most ``truncation`` metres.
        truncation: occlusion tolerance in metres (the TSDF truncation, 6 cm).
        groups: optional ``(starts [G + 1], boxes [G, 2, 3])``: the vertices ``starts[g]:starts[g + 1]`` lie in the
            box ``boxes[g]`` (min and max corners, metres); ``vertices`` is then only sliced, a range of rows at a
            time (an array, or rows read from disk: :class:`slam.model.block_mesh.DiskRows`). A frame then projects only the groups whose box's
            bounding ball meets its view (and, with depth, comes nearer than the frame's farthest depth plus
            ``truncation``): the same answer, without projecting the whole mesh into every frame.

    A vertex is in a frame if it is in front of the camera and strictly inside the image
    (``0 < u < W``, ``0 < v < H``), the reference rule.
    """
    v = _np(vertices).reshape(-1, 3) if groups is None else vertices  # groups: sliced a range at a time
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
        for a, b in ranges_in_view(len(v), groups, pose, k, depth, truncation):
            for s in range(a, b, CHUNK):  # a chunk at a time: the temporaries stay small for a large mesh
                e = min(s + CHUNK, b)
                seen[s:e] |= _in_view(np.asarray(v[s:e], np.float64), pose, k, depth, truncation)
    return seen


def ranges_in_view(n: int, groups, pose: np.ndarray, k, depth: np.ndarray | None,
                   truncation: float) -> list:
    """``[(start, end)]`` vertex ranges one frame (camera-to-world ``pose [4, 4]``, its ``depth [H, W]`` or None)
    must project: all ``n``, or the runs of ``groups`` (see :func:`visible_vertices`) whose ball (the box's centre
    and half diagonal) may hold a vertex the frame sees."""
    if groups is None:
        return [(0, n)]
    starts, boxes = groups
    centre = boxes.mean(1)
    radius = np.linalg.norm(boxes[:, 1] - boxes[:, 0], axis=1) / 2 + 1e-4  # float32 vertices may round out
    p = (centre - pose[:3, 3]) @ pose[:3, :3]
    # the frustum's side planes through the camera centre, normals inward: n . p > 0 inside (0 < u < W, 0 < v < H)
    normals = np.array([[k.fx, 0, k.cx], [-k.fx, 0, k.width - k.cx], [0, k.fy, k.cy], [0, -k.fy, k.height - k.cy]])
    near = (p[:, 2] + radius > 0) & (p @ normals.T + radius[:, None] * np.linalg.norm(normals, axis=1) > 0).all(1)
    if depth is not None:
        finite = depth[np.isfinite(depth)]
        near &= p[:, 2] - radius <= (finite.max() if finite.size else 0.0) + truncation
    edges = np.flatnonzero(np.diff(np.concatenate([[False], near, [False]]).astype(np.int8)))
    return [(int(starts[a]), int(starts[b])) for a, b in zip(edges[::2], edges[1::2])]


#: vertices projected at a time by :func:`visible_vertices`
CHUNK = 1 << 16


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
