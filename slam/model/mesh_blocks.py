"""Block extraction (docs/slam.md, "The pipeline (as implemented)", Meshing): marching cubes only in the blocks of
the grid near what the keyframes observed, so memory and work follow the surface, not the box.

The marching-cubes grid (:mod:`slam.model.mc_grid`) is cut into blocks of ``cells`` cells per edge; a block holds
its ``cells + 1`` samples per axis, so neighbouring blocks share the samples of their common face and every cell
(cube) belongs to exactly one block. The blocks kept are those within ``radius`` of an observed voxel (the
back-projected keyframe depth, voxelised: :func:`observed_voxels`). Each kept block is sampled with the same
masking as the dense extraction (-1 outside the scene box and the visibility hull), marched on its own, and its
vertices on the block's faces are welded to the ones its neighbours made on the same grid edge (keyed by the edge's
integer grid coordinates), so the mesh is the dense one wherever the dense one crosses zero in a kept block.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch
from skimage import measure

from slam.model.block_mesh import BlockMesh
from slam.model.mc_grid import QUERY, McGrid, mc_grid, sample_sdf


@dataclass(frozen=True)
class Observed:
    """Where the keyframes observed surface: ``voxels [M, 3]`` int64 indices of the voxels of edge ``size`` metres
    (the scene's truncation) that hold a back-projected depth point; the block extraction keeps the blocks within
    ``size`` of one (the band the SDF is fitted in around observed depth)."""

    voxels: np.ndarray
    size: float


def voxels_of(points: np.ndarray, size: float) -> np.ndarray:
    """``[M, 3]`` int64 distinct voxels ``floor(p / size)`` of ``points [P, 3]`` (metres), voxel edge ``size``
    metres, sorted."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return _unpack(np.unique(_pack(np.floor(points[np.isfinite(points).all(1)] / size))))


def observed_voxels(depths, c2ws, intrinsics, size: float) -> np.ndarray:
    """The voxels (edge ``size`` metres) holding a back-projected valid depth pixel of some frame.

    Args:
        depths: iterable of ``[H, W]`` depth maps in metres (0 invalid; None: skipped); c2ws: ``[4, 4]``
            camera-to-world per map (OpenCV axes). Both may be generators: one frame is held at a time.
        intrinsics: of the depth maps.

    Returns:
        ``[M, 3]`` int64 voxel indices (the voxel ``v`` spans ``[v size, (v + 1) size)`` metres), sorted.
    """
    k = intrinsics
    found = [np.zeros(0, np.int64)]
    for i, (D, T) in enumerate(zip(depths, c2ws)):
        if D is None:
            continue
        D = torch.as_tensor(D).detach().cpu().numpy().astype(np.float64)  # numpy: a small map, no thread pool
        T = torch.as_tensor(T).detach().cpu().numpy().astype(np.float64)
        v, u = np.nonzero(D > 0)
        z = D[v, u]
        cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], 1)  # slam.core.camera.backproject
        found.append(np.unique(_pack(np.floor((cam @ T[:3, :3].T + T[:3, 3]) / size))))
        if i % 64 == 63:  # merge now and then: frames of one place repeat each other's voxels
            found = [np.unique(np.concatenate(found))]
    return _unpack(np.unique(np.concatenate(found)))


#: voxel indices packed into one int64 (21 bits an axis, offset to be non-negative): +-1e6 voxels, +-60 km at 6 cm
_BITS, _OFFSET = 21, 1 << 20


def _pack(v: np.ndarray) -> np.ndarray:
    v = np.clip(v, -_OFFSET, _OFFSET - 1).astype(np.int64) + _OFFSET
    return (v[:, 0] << 2 * _BITS) | (v[:, 1] << _BITS) | v[:, 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    mask = (1 << _BITS) - 1
    return np.stack([keys >> 2 * _BITS, (keys >> _BITS) & mask, keys & mask], 1) - _OFFSET


def observed_blocks(voxels: np.ndarray, size: float, grid: McGrid, cells: int, radius: float) -> np.ndarray:
    """The blocks of ``grid`` that meet some voxel of ``voxels [M, 3]`` (edge ``size`` metres) grown by ``radius``
    metres on every side: ``[K, 3]`` int64 block indices, sorted (block ``b`` holds the cells ``b cells`` to
    ``(b + 1) cells - 1`` on each axis)."""
    nb = np.array([-(-(n - 1) // cells) for n in grid.shape])
    if not len(voxels):
        return np.zeros((0, 3), np.int64)
    edge = cells * np.asarray(grid.spacing)
    first = np.floor((voxels * size - radius - grid.lo) / edge).astype(np.int64)
    last = np.floor(((voxels + 1) * size + radius - grid.lo) / edge).astype(np.int64)
    first, last = np.maximum(first, 0), np.minimum(last, nb - 1)
    ok = (first <= last).all(1)
    first, span = first[ok], (last - first)[ok]
    found = []
    for off in itertools.product(*(range(int(s) + 1) for s in span.max(0, initial=0))):
        sel = (span >= off).all(1)
        b = first[sel] + np.asarray(off)
        found.append((b[:, 0] * nb[1] + b[:, 1]) * nb[2] + b[:, 2])
    keys = np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
    return np.stack([keys // (nb[1] * nb[2]), keys // nb[2] % nb[1], keys % nb[2]], 1)


def extract_near(scene, bound, resolution: float, observed: Observed, cells: int, batch: int = 500000, hull=None,
                 device: str | torch.device = "cpu") -> BlockMesh:
    """:func:`extract_blocks` of the blocks of the grid over ``bound`` (:func:`slam.model.mc_grid.mc_grid` at
    ``resolution``) within ``observed.size`` of an observed voxel."""
    grid = mc_grid(bound, resolution)
    blocks = observed_blocks(observed.voxels, observed.size, grid, cells, observed.size)
    return extract_blocks(scene, grid, blocks, cells, batch, hull, device)


@torch.no_grad()
def extract_blocks(scene, grid: McGrid, blocks: np.ndarray, cells: int, batch: int = 500000, hull=None,
                   device: str | torch.device = "cpu") -> BlockMesh:
    """Marching cubes of the scene's SDF in ``blocks`` (``[K, 3]`` of :func:`observed_blocks`) of ``grid``.

    Args:
        scene: :class:`slam.model.scene.SceneModel`; cells: cells per block edge; batch: points per SDF query;
            hull: :class:`slam.model.mesher.Hull` (points outside get SDF -1) or None.

    Returns:
        The blocks' mesh, closed (welded), not yet culled or coloured: use it as a context manager.
    """
    out = BlockMesh()
    try:
        # not inside tdfields.frozen: a frozen Six-axis field caches its whole composed planes (over 100 MB for the
        # walk's appearance); a block's query composes only the region it spans
        aabb = scene.aabb.detach().cpu().numpy().astype(np.float64)
        lines = hull.x_intervals(grid.axes[1], grid.axes[2]) if hull is not None else None
        for b in blocks:
            box = [slice(int(i) * cells, min((int(i) + 1) * cells, n - 1) + 1) for i, n in zip(b, grid.shape)]
            block_lines = None if lines is None else (lines[0][box[1], box[2]], lines[1][box[1], box[2]])
            sdf = sample_sdf(scene, *(a[s] for a, s in zip(grid.axes, box)), aabb, block_lines, min(batch, QUERY),
                             device)
            if sdf.min() < 0 < sdf.max():
                local, faces, _, _ = measure.marching_cubes(sdf, level=0.0, gradient_direction="ascent")
                start = np.array([s.start for s in box])
                rows, keys = edge_keys(local, start, np.array(sdf.shape) - 1, grid.shape)
                corners = np.array([[a[s][0], a[s][-1]] for a, s in zip(grid.axes, box)]).T
                out.add(grid.lo + (local.astype(np.float64) + start) * grid.spacing, faces, corners, rows, keys)
        out.close()
    except BaseException:
        out.__exit__(None, None, None)
        raise
    return out


def edge_keys(local: np.ndarray, start: np.ndarray, extent: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of one block that lie on the block's faces, and the keys of their grid edges.

    Args:
        local: ``[V, 3]`` marching-cubes vertices in sample units from the block's first sample ``start [3]``
            (skimage, spacing 1, puts every vertex on a grid edge: all its coordinates but the edge's are whole
            numbers, exactly); extent: ``[3]`` the block's samples per axis minus one; shape: the grid's samples.

    Returns:
        ``(rows [S], keys [S])``: indices into ``local`` and int64 keys, equal exactly for the same grid edge (its
        low end's grid index and its axis; axis 3: the vertex is a sample itself).
    """
    whole = local == np.round(local)
    rows = np.flatnonzero((whole & ((local == 0) | (local == extent))).any(1))
    low = np.floor(local[rows]).astype(np.int64) + start  # the edge's low end in grid samples
    axis = np.where(whole[rows].all(1), 3, np.argmin(whole[rows], 1))
    return rows, ((low[:, 0] * shape[1] + low[:, 1]) * shape[2] + low[:, 2]) * 4 + axis
