"""The marching-cubes grid and its samples (docs/slam.md, "The pipeline (as implemented)", Meshing): the sample
positions over the padded marching-cubes bound, the masked SDF on any box of them, and a coloured mesh from
marching-cubes vertices.

The dense extraction (:func:`slam.model.mesher.extract_mesh`) samples the whole grid, the block extraction
(:mod:`slam.model.mesh_blocks`) boxes of it; both sample through :func:`sample_sdf` from the same axes, so a grid
point has the same SDF value in both.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:  # imported where a Trimesh is made: 36 MB of modules that a streamed PLY does not need
    import trimesh


#: points per SDF or colour query of the block extraction at most (``meshing.batch`` may ask fewer): a colour
#: query's temporaries take almost a kilobyte a point (57 MB at 65536 points on the walk's map)
QUERY = 16384


@dataclass(frozen=True)
class McGrid:
    """Sample positions of the marching-cubes grid.

    Attributes:
        lo: ``[3]`` metres, the first sample (the bound's low corner less 0.05).
        axes: per axis the ``[n_a]`` sample coordinates in metres (``np.linspace(lo, hi, n_a)``).
        spacing: per axis the distance of neighbouring samples in metres (the resolution, rounded to fit).
    """

    lo: np.ndarray
    axes: tuple[np.ndarray, np.ndarray, np.ndarray]
    spacing: tuple[float, float, float]

    @property
    def shape(self) -> tuple[int, int, int]:
        """Samples per axis."""
        return tuple(len(a) for a in self.axes)


def mc_grid(bound, resolution: float) -> McGrid:
    """The grid over ``bound`` (``(3, 2)`` metres) padded by 0.05 m on every side, at about ``resolution`` metres:
    ``n_a = max(round((extent_a + 0.1) / resolution), 2)`` samples per axis."""
    b = np.asarray(torch.as_tensor(bound, dtype=torch.float64).tolist())
    lo = b[:, 0] - 0.05
    hi = b[:, 1] + 0.05
    n = [max(int(round((hi[a] - lo[a]) / resolution)), 2) for a in range(3)]
    axes = tuple(np.linspace(lo[a], hi[a], n[a]) for a in range(3))
    spacing = tuple(float((hi[a] - lo[a]) / (n[a] - 1)) for a in range(3))
    return McGrid(lo, axes, spacing)


def sample_sdf(scene, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, aabb: np.ndarray, lines, chunk: int,
               device) -> np.ndarray:
    """The scene's SDF on the grid points ``xs x ys x zs`` (1-D metres), -1 outside ``aabb`` (``(3, 2)`` metres) or
    outside the visibility hull, where nothing is queried.

    Args:
        lines: the hull's ``(lo, hi)`` x-intervals ``[len(ys), len(zs)]`` (:meth:`slam.model.mesher.Hull.x_intervals`
            of ``ys, zs``), or None for no hull.
        chunk: points per SDF query.

    Returns:
        ``[len(xs), len(ys), len(zs)]`` float32 (normalised SDF, as :meth:`slam.model.scene.SceneModel.sdf`).
    """
    pts = np.stack(np.broadcast_arrays(xs[:, None, None], ys[None, :, None], zs[None, None, :]), -1).reshape(-1, 3)
    inside = ((pts >= aabb[:, 0]) & (pts <= aabb[:, 1])).all(1)
    if lines is not None:
        x = xs[:, None, None]
        inside &= ((lines[0][None] <= x) & (x <= lines[1][None])).reshape(-1)
    vals = np.full(len(pts), -1.0, np.float32)
    idx = np.nonzero(inside)[0]
    for c in range(0, len(idx), chunk):
        q = torch.from_numpy(pts[idx[c:c + chunk]]).float().to(device)
        vals[idx[c:c + chunk]] = scene.sdf(q).float().cpu().numpy()
    return vals.reshape(len(xs), len(ys), len(zs))


def empty_mesh() -> trimesh.Trimesh:
    """A mesh without vertices or faces (no zero crossing)."""
    import trimesh

    return trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), np.int64), process=False)


def vertex_colors(scene, verts: np.ndarray, batch: int, device) -> np.ndarray:
    """``[V, 4]`` uint8 RGBA of ``verts [V, 3]`` (world metres) from the scene's RGB decoder (alpha 255), queried
    ``batch`` vertices at a time (inside :func:`tdfields.frozen` the fields' composed planes serve every batch;
    outside it a query composes only the region its vertices span)."""
    rgba = np.full((len(verts), 4), 255, np.uint8)
    with torch.no_grad():
        for s in range(0, len(verts), batch):
            v = torch.from_numpy(np.asarray(verts[s:s + batch], np.float32)).to(device)
            rgba[s:s + batch, :3] = (scene.rgb(v).clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
    return rgba


def colored_mesh(scene, verts: np.ndarray, faces: np.ndarray, batch: int, device) -> trimesh.Trimesh:
    """``trimesh.Trimesh`` of ``verts [V, 3]`` (world metres) and ``faces [F, 3]`` with :func:`vertex_colors`."""
    import trimesh

    return trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=vertex_colors(scene, verts, batch, device),
                           process=False)
