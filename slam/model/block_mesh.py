"""A mesh marched block by block (:mod:`slam.model.mesh_blocks`), held compactly until it is written, so the memory
of meshing a large map stays far below the mesh's own size in a ``trimesh.Trimesh``.

Each block appends its vertices (float32 world metres) and faces (int32) to temporary files as it is marched, and
they are read back a range at a time. A vertex on a block's face is made by both blocks that share the face: the
second copy is welded onto the first by the key of its grid edge (:meth:`BlockMesh.close`), and is then never
referenced. Culling (:meth:`BlockMesh.cull`) projects each frame's view only into the blocks it can see (on the
40 m walk, a seventh of the vertices per frame); the faces are then streamed from disk, welded, culled and
renumbered, into a ``trimesh.Trimesh`` (:meth:`BlockMesh.trimesh`) or straight into a binary PLY
(:meth:`BlockMesh.write_ply`), the vertices coloured block by block.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slam.eval.culling import visible_vertices
from slam.model.mc_grid import QUERY, empty_mesh, vertex_colors

if TYPE_CHECKING:  # imported where a Trimesh is made: 36 MB of modules that a streamed PLY does not need
    import trimesh

#: faces or vertices streamed from disk at a time (a few MB each, and their temporaries)
CHUNK = 1 << 18
#: a binary PLY face: the vertex count (3) and three int32 indices, packed (13 bytes)
PLY_FACE = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
PLY_VERTEX = np.dtype([("xyz", "<f4", (3,)), ("rgba", "u1", (4,))])


class BlockMesh:
    """The blocks' vertices and faces as they are marched; a context manager (the temporary files go on leaving).

    Attributes:
        vertices: ``[V, 3]`` float32 world metres of every vertex added (welded copies included), read from disk
            when sliced (:class:`DiskRows`), after :meth:`close`.
        starts, boxes: ``[K + 1]`` and ``[K, 2, 3]``: block ``b``'s vertices are ``starts[b]:starts[b + 1]``, inside
            its box (min and max corner, metres).
    """

    def __init__(self):
        self._dir = tempfile.TemporaryDirectory(prefix="lrslam-mesh-")
        self._vfile = open(Path(self._dir.name) / "vertices.f32", "w+b")
        self._ffile = open(Path(self._dir.name) / "faces.i32", "w+b")
        self.count, self.face_count = 0, 0
        self.starts, self.boxes = [0], []
        self._keys: list[np.ndarray] = []
        self._ids: list[np.ndarray] = []
        self.vertices = self._rep = self.seen = None

    def __enter__(self) -> BlockMesh:
        return self

    def __exit__(self, *exc) -> None:
        self._vfile.close()
        self._ffile.close()
        self._dir.cleanup()

    def add(self, verts: np.ndarray, faces: np.ndarray, box: np.ndarray, rows: np.ndarray, keys: np.ndarray) -> None:
        """One block: ``verts [n, 3]`` world metres, ``faces [m, 3]`` indexing them, its ``box [2, 3]``; the vertices
        ``rows`` lie on the block's faces, with the grid-edge ``keys [len(rows)]`` int64 (equal keys: one vertex)."""
        self._vfile.write(np.ascontiguousarray(verts, np.float32).tobytes())
        self._ffile.write(np.ascontiguousarray(faces + self.count, np.int32).tobytes())
        self._keys.append(keys)
        self._ids.append(rows + self.count)
        self.count += len(verts)
        self.face_count += len(faces)
        self.starts.append(self.count)
        self.boxes.append(box)
        if self.count >= 2 ** 31:
            raise ValueError("more than 2^31 mesh vertices: use a coarser resolution")

    def close(self) -> None:
        """Every block added: the vertices become readable (:attr:`vertices`) and the copies on block faces are
        welded (each key's first vertex stands for all of its copies)."""
        self._vfile.flush()
        self._ffile.flush()
        self.vertices = DiskRows(self._vfile.name, self.count)
        self._rep = np.arange(self.count, dtype=np.int32)
        keys, ids = (np.concatenate(self._keys), np.concatenate(self._ids)) if self._keys else ((),) * 2
        if len(keys):
            order = np.argsort(keys, kind="stable")  # ids grow with the blocks: a key's first is its smallest id
            keys, ids = keys[order], ids[order]
            first = np.concatenate([[True], keys[1:] != keys[:-1]])
            self._rep[ids] = ids[first][np.cumsum(first) - 1]
        self._keys = self._ids = []

    def cull(self, poses, intrinsics, depths=None, truncation: float = 0.06) -> None:
        """Keep only the faces some frame saw a vertex of (:func:`slam.eval.culling.visible_vertices`, the rule of
        :func:`slam.eval.cull_mesh`), each frame projected into the blocks it can see only."""
        groups = (np.asarray(self.starts), np.asarray(self.boxes, np.float64).reshape(-1, 2, 3))
        self.seen = visible_vertices(self.vertices, poses, intrinsics, depths, truncation, groups=groups)

    def _faces(self):
        """The welded faces kept by :meth:`cull`, a chunk at a time (``[m, 3]`` int32, indices into
        :attr:`vertices`)."""
        with open(self._ffile.name, "rb") as fh:
            while chunk := fh.read(CHUNK * 12):
                f = self._rep[np.frombuffer(chunk, np.int32).reshape(-1, 3)]
                yield f if self.seen is None else f[self.seen[f].any(1)]

    def _renumbered(self) -> tuple[np.ndarray, int]:
        """``(new [V], kept)``: each referenced vertex's index in the written mesh (-1: not written), faces kept."""
        used = np.zeros(self.count, bool)
        kept = 0
        for f in self._faces():
            used[f] = True
            kept += len(f)
        new = np.cumsum(used, dtype=np.int32)  # add() keeps the count below 2^31
        new -= 1
        new[~used] = -1
        return new, kept

    def _kept(self, new: np.ndarray, scene, batch: int, device):
        """The written vertices block by block: ``(xyz [n, 3] float32, rgba [n, 4] uint8)``, coloured by the scene's
        RGB decoder one block at a time (a query composes only the block's region of a Six-axis field's planes)."""
        for a, b in zip(self.starts[:-1], self.starts[1:]):
            xyz = self.vertices[a:b][new[a:b] >= 0]
            if len(xyz):
                yield xyz, vertex_colors(scene, xyz, min(batch, QUERY), device)

    def trimesh(self, scene, batch: int, device) -> trimesh.Trimesh:
        """The welded (and culled) mesh, coloured by the scene's RGB decoder."""
        import trimesh

        new, kept = self._renumbered()
        if not kept:
            return empty_mesh()
        xyz, rgba = zip(*self._kept(new, scene, batch, device))
        faces = np.concatenate([new[f] for f in self._faces()]).astype(np.int64)
        return trimesh.Trimesh(vertices=np.concatenate(xyz).astype(np.float64), faces=faces,
                               vertex_colors=np.concatenate(rgba), process=False)

    def write_ply(self, path, scene, batch: int, device) -> tuple[int, int]:
        """Write the welded (and culled) mesh as a binary little-endian PLY at ``path`` (the layout trimesh writes:
        float32 xyz, uchar RGBA, int32 triangles), streamed: ``(vertices, faces)`` written."""
        new, kept = self._renumbered()
        count = int((new >= 0).sum())
        with open(path, "wb") as fh:
            fh.write((f"ply\nformat binary_little_endian 1.0\ncomment lrslam\nelement vertex {count}\n"
                      "property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
                      f"property uchar blue\nproperty uchar alpha\nelement face {kept}\n"
                      "property list uchar int vertex_indices\nend_header\n").encode("ascii"))
            for xyz, rgba in self._kept(new, scene, batch, device):
                rec = np.empty(len(xyz), PLY_VERTEX)
                rec["xyz"], rec["rgba"] = xyz, rgba
                fh.write(rec.tobytes())
            for f in self._faces():
                rec = np.empty(len(f), PLY_FACE)
                rec["n"], rec["v"] = 3, new[f]
                fh.write(rec.tobytes())
        return count, kept


class DiskRows:
    """``[n, 3]`` float32 rows of a raw file, read when sliced (``rows[a:b]``: an ``[b - a, 3]`` array): the
    vertices culling projects group by group, never all held at once."""

    def __init__(self, path: str, n: int):
        self.path, self.n = path, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, rows: slice) -> np.ndarray:
        a, b, step = rows.indices(self.n)
        if step != 1:
            raise IndexError("DiskRows reads contiguous rows only")
        return np.fromfile(self.path, np.float32, count=3 * max(b - a, 0), offset=12 * a).reshape(-1, 3)
