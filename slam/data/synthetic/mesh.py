"""The ground-truth mesh: trimesh primitives matching the analytic surfaces, with the faces no camera in the room
can see removed and vertex colours from the textures."""

from __future__ import annotations

import numpy as np

from slam.data.synthetic.scene import SynthScene
from slam.data.synthetic.textures import albedo


def scene_mesh(scene: SynthScene, max_edge: float = 0.1, drop_hidden: bool = True):
    """Ground-truth ``trimesh.Trimesh`` of the scene (room faces inward), edges split to <= ``max_edge`` m.

    Short edges keep vertex-based culling (:func:`slam.eval.cull_mesh`) fine-grained. With ``drop_hidden``
    faces that no camera inside the room can ever see are removed: faces inside or touching another solid
    (floor under furniture, box bottoms, a vase's base on the table, the wall behind the shelf) and object
    faces lying on the room boundary. Like a scanned GT mesh, it then holds only surfaces that exist to a
    sensor. Vertex colours are the texture albedo.
    """
    import trimesh

    rmin, rmax = scene.room_min, scene.room_max
    parts = []
    room = trimesh.creation.box(extents=rmax - rmin)
    room.apply_translation((rmax + rmin) / 2)
    room.invert()  # normals point into the room, the side the camera sees
    parts.append(room)
    for bmin, bmax, _ in scene.boxes:
        m = trimesh.creation.box(extents=bmax - bmin)
        m.apply_translation((bmax + bmin) / 2)
        parts.append(m)
    for c, r, _ in scene.spheres:
        m = trimesh.creation.icosphere(subdivisions=4, radius=r)
        m.apply_translation(c)
        parts.append(m)
    for cxy, r, z0, z1, _ in scene.cylinders:
        m = trimesh.creation.cylinder(radius=r, height=z1 - z0, sections=96)
        m.apply_translation([cxy[0], cxy[1], (z0 + z1) / 2])
        parts.append(m)
    meshes = []
    for k, m in enumerate(parts):
        v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=max_edge)
        if drop_hidden:
            centroids = v[f].mean(axis=1)
            hidden = _inside_solids(scene, centroids, skip=k - 1)
            if k > 0:
                hidden |= np.any((centroids < rmin + 1e-3) | (centroids > rmax - 1e-3), axis=1)
            f = f[~hidden]
        part = trimesh.Trimesh(v, f, process=False)
        part.remove_unreferenced_vertices()
        meshes.append(part)
    mesh = trimesh.util.concatenate(meshes)
    # colour by the nearest analytic surface (room faces by which wall they lie on)
    mats = _vertex_materials(scene, mesh.vertices)
    col = albedo(scene, mesh.vertices, mats)
    mesh.visual.vertex_colors = np.concatenate([np.round(col * 255), np.full((len(col), 1), 255)], 1).astype(np.uint8)
    return mesh


def _inside_solids(scene: SynthScene, p: np.ndarray, skip: int = -1, eps: float = 1e-3) -> np.ndarray:
    """``[P]`` True where points lie inside or within ``eps`` of any solid except number ``skip``
    (solids numbered boxes, then spheres, then cylinders)."""
    inside = np.zeros(len(p), bool)
    k = 0
    for bmin, bmax, _ in scene.boxes:
        if k != skip:
            inside |= np.all((p >= bmin - eps) & (p <= bmax + eps), axis=1)
        k += 1
    for c, r, _ in scene.spheres:
        if k != skip:
            inside |= np.linalg.norm(p - c, axis=1) <= r + eps
        k += 1
    for cxy, r, z0, z1, _ in scene.cylinders:
        if k != skip:
            inside |= (np.linalg.norm(p[:, :2] - cxy, axis=1) <= r + eps) & (p[:, 2] >= z0 - eps) & (p[:, 2] <= z1 + eps)
        k += 1
    return inside


def _vertex_materials(scene: SynthScene, v: np.ndarray) -> np.ndarray:
    best = np.full(len(v), np.inf)
    mat = np.zeros(len(v), np.int64)
    # room faces
    lo, hi = scene.room_min, scene.room_max
    dists = np.stack([v[:, 0] - lo[0], hi[0] - v[:, 0], v[:, 1] - lo[1], hi[1] - v[:, 1], v[:, 2] - lo[2],
                      hi[2] - v[:, 2]], 1)
    best = np.abs(dists).min(1)
    mat = np.abs(dists).argmin(1)
    for bmin, bmax, mid in scene.boxes:
        q = np.maximum(np.maximum(bmin - v, v - bmax), 0)
        inside = np.minimum(np.maximum(bmin - v, v - bmax).max(1), 0)
        dd = np.abs(np.linalg.norm(q, axis=1) + inside)
        upd = dd < best - 1e-9
        best[upd], mat[upd] = dd[upd], mid
    for c, r, mid in scene.spheres:
        dd = np.abs(np.linalg.norm(v - c, axis=1) - r)
        upd = dd < best - 1e-9
        best[upd], mat[upd] = dd[upd], mid
    for cxy, r, z0, z1, mid in scene.cylinders:
        rad = np.abs(np.linalg.norm(v[:, :2] - cxy, axis=1) - r)
        ax = np.maximum(np.maximum(z0 - v[:, 2], v[:, 2] - z1), 0)
        dd = np.hypot(rad, ax)
        upd = dd < best - 1e-9
        best[upd], mat[upd] = dd[upd], mid
    return mat
