"""Block extraction: the dense extraction's mesh, from the blocks near observed depth only."""

import itertools

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from slam.data import Intrinsics
from slam.model.mc_grid import mc_grid
from slam.model.mesh_blocks import Observed, extract_blocks, observed_blocks, observed_voxels, voxels_of
from slam.model.mesher import Hull, extract_mesh

BOUND = [[-1.0, 2.0], [-1.0, 1.5], [-0.5, 1.2]]
ROOM = np.array([[-0.8, 1.8], [-0.8, 1.3], [-0.3, 1.0]])
BALL, RADIUS = np.array([0.5, 0.2, 0.3]), 0.37


class Room(torch.nn.Module):
    """An analytic scene: the inside of a box room (walls, floor, ceiling) with a ball standing in it; the SDF as
    the model gives it (tanh of metres over a 6 cm truncation), colours from the position."""

    def __init__(self):
        super().__init__()
        self.register_buffer("aabb", torch.tensor(BOUND))

    @staticmethod
    def metres(p: np.ndarray) -> np.ndarray:
        room = np.minimum(p - ROOM[:, 0], ROOM[:, 1] - p).min(-1)
        return np.minimum(room, np.linalg.norm(p - BALL, axis=-1) - RADIUS)

    def sdf(self, p):
        return torch.from_numpy(np.tanh(self.metres(p.double().numpy()) / 0.06)).float()

    def rgb(self, p):
        return torch.sigmoid(torch.sin(p * 5))


def _surface(n: int, rng) -> np.ndarray:
    """``[n, 3]`` points on the room's surfaces and the ball (what a depth camera inside would observe)."""
    pts = rng.uniform(ROOM[:, 0], ROOM[:, 1], (n, 3))
    axis, side = rng.integers(0, 3, n), rng.integers(0, 2, n)
    pts[np.arange(n), axis] = ROOM[axis, side]
    d = rng.normal(size=(n // 4, 3))
    return np.concatenate([pts, BALL + RADIUS * d / np.linalg.norm(d, axis=1, keepdims=True)])


def _same_mesh(a, b) -> bool:
    """Same vertices (up to order and float rounding) and the same faces on them, orientation included."""
    dist, match = cKDTree(a.vertices).query(b.vertices)
    if len(a.vertices) != len(b.vertices) or dist.max() > 1e-6 or len(np.unique(match)) != len(match):
        return False

    def faces(f):  # each face from its smallest vertex index, keeping the winding
        f = np.asarray(f)
        roll = (np.argmin(f, 1)[:, None] + np.arange(3)) % 3
        return set(map(tuple, np.take_along_axis(f, roll, 1).tolist()))

    return faces(match[b.faces]) == faces(a.faces)


@pytest.mark.parametrize("resolution, cells", [(0.05, 7), (0.04, 32)])
def test_blocks_near_the_observed_surface_give_the_dense_mesh(resolution, cells):
    """With the observed surface covering every zero crossing, the block mesh is the dense one: same vertices, same
    faces (winding included), same colours; blocks of 7 cells do not divide the grid (short last blocks), and the
    hull cuts the room (masked samples on block faces)."""
    rng = np.random.default_rng(0)
    scene = Room()
    hull = Hull(rng.uniform(BOUND[0][0], 1.6, (300, 3)) * [1, 0.9, 0.8], 1.02)
    dense = extract_mesh(scene, BOUND, resolution, hull=hull)
    observed = Observed(voxels_of(_surface(20000, rng), 0.06), 0.06)
    blocks = extract_mesh(scene, BOUND, resolution, hull=hull, observed=observed, block_cells=cells)
    assert len(dense.faces) > 1000 and len(blocks.faces) == len(dense.faces)
    assert _same_mesh(dense, blocks)
    _, match = cKDTree(dense.vertices).query(blocks.vertices)
    assert np.array_equal(dense.visual.vertex_colors[match], blocks.visual.vertex_colors)


def test_block_seams_are_welded_and_unobserved_surfaces_left_out():
    """Only the ball observed: its blocks (2 cells, 10 cm) reach 20 cm from it, short of the floor (23 cm), so the
    room's walls are not meshed; the ball, cut by block faces on every axis, comes out closed: each vertex on a seam
    is one vertex."""
    d = np.random.default_rng(2).normal(size=(4000, 3))
    near = Observed(voxels_of(BALL + RADIUS * d / np.linalg.norm(d, axis=1, keepdims=True), 0.05), 0.05)
    grid = mc_grid(BOUND, 0.05)
    blocks = observed_blocks(near.voxels, near.size, grid, 2, near.size)
    with extract_blocks(Room(), grid, blocks, 2) as made:
        mesh = made.trimesh(Room(), 1000, "cpu")
    assert (np.linalg.norm(mesh.vertices - BALL, axis=1) < RADIUS + 0.05).all()
    assert len(np.unique(blocks[:, 0])) > 5 and mesh.is_watertight and len(mesh.split(only_watertight=True)) == 1


def test_culled_and_written_a_chunk_at_a_time_it_is_cull_mesh_of_the_whole(tmp_path, monkeypatch):
    """Culling the blocks (each frame projected into the blocks it can see) keeps what ``cull_mesh`` keeps of the
    whole mesh, and the PLY streamed a chunk at a time is that mesh, colours included."""
    import trimesh

    from slam.eval import cull_mesh
    from slam.model import block_mesh

    monkeypatch.setattr(block_mesh, "CHUNK", 999)
    scene, grid = Room(), mc_grid(BOUND, 0.04)
    observed = Observed(voxels_of(_surface(20000, np.random.default_rng(3)), 0.06), 0.06)
    k = Intrinsics(30.0, 30.0, 19.5, 14.5, 30, 40)
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[0, :3, 3] = [0.5, 0.2, -0.2]  # looking up +z from the floor
    poses[1, :3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # looking along +x from the room's -x side
    poses[1, :3, 3] = [-0.7, 0.2, 0.3]
    depths = [np.full((30, 40), 0.9), np.full((30, 40), 1.6)]
    with extract_blocks(scene, grid, observed_blocks(observed.voxels, 0.06, grid, 8, 0.06), 8) as made:
        whole = made.trimesh(scene, 1000, "cpu")
        made.cull(poses, k, depths, 0.06)
        culled = made.trimesh(scene, 1000, "cpu")
        assert made.write_ply(tmp_path / "m.ply", scene, 1000, "cpu") == (len(culled.vertices), len(culled.faces))
    ref = cull_mesh(whole, poses, k, depths, 0.06)
    assert 0 < len(culled.faces) < len(whole.faces) / 2
    assert np.array_equal(culled.faces, ref.faces) and np.array_equal(culled.vertices, ref.vertices)
    written = trimesh.load(tmp_path / "m.ply", process=False)
    assert np.array_equal(written.faces, culled.faces) and np.allclose(written.vertices, culled.vertices, atol=0)
    assert np.array_equal(written.visual.vertex_colors, culled.visual.vertex_colors)


def test_observed_blocks_are_the_blocks_meeting_the_grown_voxels():
    """Oracle: a block is kept exactly when its cells' box meets a voxel's box grown by the radius."""
    rng = np.random.default_rng(1)
    grid = mc_grid(BOUND, 0.03)
    size, radius, cells = 0.06, 0.05, 4
    voxels = rng.integers(-22, 40, (40, 3))
    got = {tuple(b) for b in observed_blocks(voxels, size, grid, cells, radius).tolist()}
    nb = [-(-(n - 1) // cells) for n in grid.shape]
    want = set()
    for b in itertools.product(*(range(k) for k in nb)):
        lo = grid.lo + np.array(b) * cells * np.array(grid.spacing)
        hi = lo + cells * np.array(grid.spacing)
        meets = ((voxels * size - radius < hi) & ((voxels + 1) * size + radius >= lo)).all(1)
        want |= {b} if meets.any() else set()
    assert want and got == want


def test_observed_voxels_hold_every_valid_depth_pixel():
    """A fronto-parallel wall 2 m away seen by a 40x30 camera: the voxels are those of its back-projected pixels,
    a missing map (None) and invalid depth (0) add none."""
    k = Intrinsics(30.0, 30.0, 19.5, 14.5, 30, 40)
    depth = np.full((30, 40), 2.0, np.float32)
    depth[:, :5] = 0
    pose = np.eye(4)
    pose[:3, 3] = [0.3, -0.2, 0.1]
    got = observed_voxels([None, depth], [pose, pose], k, 0.1)
    v, u = np.nonzero(depth > 0)
    pts = np.stack([(u - k.cx) / k.fx * 2, (v - k.cy) / k.fy * 2, np.full(len(u), 2.0)], 1) + pose[:3, 3]
    assert np.array_equal(got, voxels_of(pts, 0.1))
    assert set(got[:, 2].tolist()) == {21}
