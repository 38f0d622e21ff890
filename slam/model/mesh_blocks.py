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
import trimesh
from skimage import measure

import tdfields
from slam.core.camera import backproject
from slam.model.mc_grid import McGrid, colored_mesh, empty_mesh, sample_sdf


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
    if not len(points):
        return np.zeros((0, 3), np.int64)
    return np.unique(np.floor(np.asarray(points, np.float64) / size).astype(np.int64), axis=0)


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
    found = []
    for D, T in zip(depths, c2ws):
        if D is None:
            continue
        D = torch.as_tensor(D).detach().cpu().float()
        T = torch.as_tensor(T).detach().cpu().double()
        v, u = torch.nonzero(D > 0, as_tuple=True)
        cam = backproject(u.double(), v.double(), D[v, u].double(), k.fx, k.fy, k.cx, k.cy)
        found.append(voxels_of((cam @ T[:3, :3].T + T[:3, 3]).numpy(), size))
    return np.unique(np.concatenate(found), axis=0) if found else np.zeros((0, 3), np.int64)


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


@torch.no_grad()
def extract_blocks(scene, grid: McGrid, blocks: np.ndarray, cells: int, batch: int = 500000, hull=None,
                   device: str | torch.device = "cpu") -> trimesh.Trimesh:
    """Marching cubes of the scene's SDF in ``blocks`` (``[K, 3]`` of :func:`observed_blocks`) of ``grid``, welded
    into one mesh and coloured.

    Args:
        scene: :class:`slam.model.scene.SceneModel`; cells: cells per block edge; batch: points per SDF and colour
            query; hull: :class:`slam.model.mesher.Hull` (points outside get SDF -1) or None.

    Returns:
        Coloured ``trimesh.Trimesh`` in world metres (empty when no zero crossing exists in the blocks).
    """
    with tdfields.frozen(scene):  # the map is fixed while meshing: Six-axis composes its planes once
        aabb = scene.aabb.detach().cpu().numpy().astype(np.float64)
        lines = hull.x_intervals(grid.axes[1], grid.axes[2]) if hull is not None else None
        weld = _Welder(grid)
        for b in blocks:
            box = [slice(int(i) * cells, min((int(i) + 1) * cells, n - 1) + 1) for i, n in zip(b, grid.shape)]
            block_lines = None if lines is None else (lines[0][box[1], box[2]], lines[1][box[1], box[2]])
            sdf = sample_sdf(scene, *(a[s] for a, s in zip(grid.axes, box)), aabb, block_lines,
                             min(batch, 65536), device)
            if sdf.min() < 0 < sdf.max():
                verts, faces, _, _ = measure.marching_cubes(sdf, level=0.0, gradient_direction="ascent")
                weld.add(verts, faces, np.array([s.start for s in box]), np.array(sdf.shape) - 1)
        if not weld.faces:
            return empty_mesh()
        verts, faces = weld.result()
        return colored_mesh(scene, verts, faces, batch, device)


class _Welder:
    """The blocks' vertices and faces, gathered compactly: a vertex on a block's face (where a neighbour makes the
    same one) is stored once, found again by the key of its grid edge."""

    def __init__(self, grid: McGrid):
        self.grid = grid
        self.shape = np.array(grid.shape, np.int64)
        self.verts: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.count = 0
        self.seen: dict[int, int] = {}  # edge key -> vertex index, for the vertices on block faces

    def add(self, local: np.ndarray, faces: np.ndarray, start: np.ndarray, extent: np.ndarray) -> None:
        """One block's marching cubes: ``local [V, 3]`` vertices in sample units from the block's first sample
        ``start [3]``, the block ``extent [3]`` samples minus one, ``faces [F, 3]``. skimage (spacing 1) puts every
        vertex on a grid edge: all its coordinates but the edge's are whole numbers, exactly."""
        whole = local == np.round(local)
        rows = np.flatnonzero((whole & ((local == 0) | (local == extent))).any(1))
        low = np.floor(local[rows]).astype(np.int64) + start  # the edge's low end in grid samples
        axis = np.where(whole[rows].all(1), 3, np.argmin(whole[rows], 1))  # 3: the vertex is a sample itself
        keys = (((low[:, 0] * self.shape[1] + low[:, 1]) * self.shape[2] + low[:, 2]) * 4 + axis).tolist()
        index = np.full(len(local), -1, np.int64)
        index[rows] = [self.seen.get(k, -1) for k in keys]
        new = index < 0
        index[new] = np.arange(self.count, self.count + int(new.sum()))
        self.count += int(new.sum())
        for r, k in zip(rows.tolist(), keys):
            self.seen.setdefault(k, int(index[r]))
        self.verts.append(self.grid.lo + (local[new].astype(np.float64) + start) * self.grid.spacing)
        self.faces.append(index[faces].astype(np.int32 if self.count < 2 ** 31 else np.int64))

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """``(verts [V, 3] float64 metres, faces [F, 3] int64)`` of all blocks added."""
        verts = np.concatenate(self.verts)
        self.verts = []
        faces = np.concatenate(self.faces).astype(np.int64)
        self.faces = []
        return verts, faces
