import numpy as np
import pytest
import trimesh

from slam.data import Intrinsics
from slam.errors import SlamInputError
from slam.eval import align_mesh, cull_mesh, depth_l1, reconstruction_metrics, render_depth
from slam.eval.mesh_metrics import look_at


def _plane(x0=0.0, x1=1.0, y0=0.0, y1=1.0, z=0.0, n=20):
    xs, ys = np.meshgrid(np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1), indexing="ij")
    v = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return trimesh.Trimesh(v, f, process=False)


def _room(half=1.0):
    m = trimesh.creation.box(extents=[2 * half] * 3)
    m.invert()
    return m


def test_shifted_plane_accuracy_equals_shift():
    gt = _plane()
    rec = _plane(z=0.02)
    m = reconstruction_metrics(rec, gt, samples=200_000)
    assert m["accuracy_m"] == pytest.approx(0.02, abs=3e-4)
    assert m["completion_m"] == pytest.approx(0.02, abs=3e-4)
    assert m["completion_ratio"] == 1.0
    far = reconstruction_metrics(_plane(z=0.06), gt, samples=50_000)
    assert far["completion_ratio"] == 0.0


def test_half_reconstruction_known_completion():
    gt = _plane()
    rec = _plane(x1=0.5, n=20)
    m = reconstruction_metrics(rec, gt, samples=200_000)
    # missing half: GT points at x in (0.5, 1] are x - 0.5 away -> mean 0.25 over that half
    assert m["accuracy_m"] < 0.002
    assert m["completion_m"] == pytest.approx(0.125, abs=0.003)
    assert m["completion_ratio"] == pytest.approx(0.5 + 0.5 * 0.05 / 0.5, abs=0.005)


def test_icp_removes_small_rigid_misalignment():
    gt = trimesh.creation.box(extents=[2.0, 1.5, 1.0]).subdivide().subdivide()
    rec = gt.copy()
    t = np.eye(4)
    t[:3, :3] = trimesh.transformations.rotation_matrix(np.radians(1.0), [0.3, 0.2, 1.0])[:3, :3]
    t[:3, 3] = [0.03, -0.02, 0.01]
    rec.apply_transform(t)
    floor = reconstruction_metrics(gt.copy(), gt, samples=50_000)["accuracy_m"]  # sample spacing only
    plain = reconstruction_metrics(rec, gt, samples=50_000)
    aligned = reconstruction_metrics(rec, gt, samples=50_000, icp=True)
    assert plain["accuracy_m"] > floor + 0.01
    assert aligned["accuracy_m"] < floor + 0.001 and aligned["completion_ratio"] == 1.0
    assert aligned["icp_translation_m"] == pytest.approx(np.linalg.norm(np.linalg.inv(t)[:3, 3]), abs=0.003)


def test_align_mesh_once_serves_both_metrics():
    gt = trimesh.creation.box(extents=[2.0, 1.5, 1.0]).subdivide().subdivide()
    t = np.eye(4)
    t[:3, :3] = trimesh.transformations.rotation_matrix(np.radians(1.0), [0.3, 0.2, 1.0])[:3, :3]
    t[:3, 3] = [0.03, -0.02, 0.01]
    rec = gt.copy()
    rec.apply_transform(t)
    aligned, transform = align_mesh(rec, gt, samples=50_000)
    np.testing.assert_allclose(transform, np.linalg.inv(t), atol=2e-3)
    np.testing.assert_allclose(rec.vertices, gt.vertices @ t[:3, :3].T + t[:3, 3])  # the input is left alone
    assert np.abs(aligned.vertices - gt.vertices).max() < 3e-3
    # depth_l1(icp=True) is depth_l1 of the copy align_mesh returns (same samples, same seed)
    box = ([-0.2, -0.2, -0.2], [0.2, 0.2, 0.2])
    kw = dict(views=3, height=40, width=40, focal=30.0, camera_box=box)
    assert depth_l1(rec, gt, icp=True, **kw) == depth_l1(align_mesh(rec, gt)[0], gt, **kw)


def test_render_depth_is_z_depth():
    room = _room(1.0)
    d = render_depth(room, look_at(np.zeros(3), np.array([1.0, 0, 0])), 41, 41, 20.0, 20.0, 20.0, 20.0)
    # the front wall x = 1 spans the central pixels; its z-depth is 1 everywhere on it
    np.testing.assert_allclose(d[15:26, 15:26], 1.0, atol=1e-5)
    assert d.min() > 0  # closed room: every ray hits


def test_depth_l1_known_answers():
    gt = _room(1.0)
    box = ([-0.001] * 3, [0.001] * 3)
    assert depth_l1(gt, gt, views=3, height=40, width=40, focal=24, camera_box=box) == pytest.approx(0.0, abs=1e-6)
    tiny = trimesh.Trimesh([[50, 50, 50], [50.01, 50, 50], [50, 50.01, 50]], [[0, 1, 2]])
    mean_depth = depth_l1(tiny, gt, views=3, height=40, width=40, focal=24, camera_box=box)  # rec sees nothing
    assert 1.0 < mean_depth < 1.7
    bigger = _room(1.1)  # from the centre every depth scales by 1.1
    d = depth_l1(bigger, gt, views=3, height=40, width=40, focal=24, camera_box=box)
    assert d == pytest.approx(0.1 * mean_depth, rel=2e-3)


def test_cull_frustum_and_occlusion():
    far = _plane(-2, 2, -2, 2, z=2.0, n=80)  # 5 cm grid
    k = Intrinsics(50.0, 50.0, 49.5, 49.5, 100, 100)  # sees [-2, 2] x 0.99 at z = 2
    cam = np.eye(4)
    half_view = np.tile(cam, (1, 1, 1))
    culled = cull_mesh(far, half_view, Intrinsics(50.0, 50.0, 49.5, 49.5, 50, 100))  # top half of the image
    assert culled.bounds[1, 1] <= 0.05 + 1e-9 and culled.bounds[0, 1] < -1.9
    assert culled.area == pytest.approx(8.0, rel=0.05)

    occluder = _plane(-0.25, 0.25, -0.25, 0.25, z=1.0, n=10)
    scene = trimesh.util.concatenate([far, occluder])
    depth = render_depth(scene, cam, 100, 100, 50.0, 50.0, 49.5, 49.5)
    vis = cull_mesh(far, cam[None], k, depths=[depth], truncation=0.06)
    # the occluder hides [-0.5, 0.5]^2 of the far plane (area 1): about 16 - 1 remains
    assert vis.area == pytest.approx(15.0, abs=0.4)
    assert cull_mesh(far, cam[None], k, depths=[depth], truncation=2.0).area == pytest.approx(16.0, rel=0.02)
    with pytest.raises(SlamInputError, match="depth map 0"):
        cull_mesh(far, cam[None], k, depths=[depth[:50]])
    # a NaN pose (invalid ground truth) is skipped, not propagated
    nan_pose = np.full((4, 4), np.nan)
    assert cull_mesh(far, np.stack([nan_pose, cam]), k).area == pytest.approx(16.0, rel=0.02)


def test_visible_vertices_a_chunk_at_a_time_is_the_same_rule(monkeypatch):
    """Vertices are projected a chunk at a time (memory), and only the groups of them a frame can see; the answer
    must not depend on either, and a depth map of NaN (an unreadable frame in ``run_mesh``) sees nothing."""
    from slam.eval import culling

    rng = np.random.default_rng(0)
    verts = rng.uniform([-2, -2, 0.5], [2, 2, 4], (5000, 3))
    k = Intrinsics(40.0, 40.0, 31.5, 23.5, 48, 64)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[1, :3, 3] = [0.5, 0, -1]
    poses[2, :3, 3] = [-0.5, 0.2, 0]
    depths = [rng.uniform(0.5, 3, (48, 64)) for _ in range(3)]
    whole = culling.visible_vertices(verts, poses, k, depths)
    monkeypatch.setattr(culling, "CHUNK", 333)
    assert 0 < whole.sum() < len(verts) and np.array_equal(culling.visible_vertices(verts, poses, k, depths), whole)
    assert not culling.visible_vertices(verts, poses[:1], k, [np.full((48, 64), np.nan)]).any()
    # vertices grouped by the 1 m cells they lie in (boxes a little larger): frames skip the groups out of view
    cell = np.floor(verts).astype(int)
    order = np.lexsort(cell.T[::-1])
    verts, cell = verts[order], cell[order]
    first = np.flatnonzero(np.concatenate([[True], (cell[1:] != cell[:-1]).any(1)]))
    boxes = np.stack([cell[first] - 0.01, cell[first] + 1.01], 1).astype(float)
    whole = culling.visible_vertices(verts, poses, k, depths)
    groups = (np.append(first, len(verts)), boxes)
    skipped = [culling.ranges_in_view(len(verts), groups, poses[i], k, depths[i], 0.06) for i in range(3)]
    assert all(sum(b - a for a, b in r) < len(verts) for r in skipped)
    assert np.array_equal(culling.visible_vertices(verts, poses, k, depths, groups=groups), whole)


def test_bad_meshes(tmp_path):
    with pytest.raises(SlamInputError, match="not found"):
        reconstruction_metrics(tmp_path / "missing.ply", _plane())
    bad = tmp_path / "bad.ply"
    bad.write_text("this is not a mesh")
    with pytest.raises(SlamInputError, match="bad.ply"):
        reconstruction_metrics(bad, _plane())
    with pytest.raises(SlamInputError, match="empty mesh"):
        reconstruction_metrics(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), _plane())
