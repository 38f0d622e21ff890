import numpy as np
import pytest
import torch

from slam.data import Intrinsics, ReplicaDataset, ScanNetDataset, load_dataset
from slam.data.replica import REPLICA_INTRINSICS
from slam.errors import SlamInputError


def _pose(i):
    p = np.eye(4)
    c, s = np.cos(0.1 * i), np.sin(0.1 * i)
    p[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    p[:3, 3] = [0.1 * i, 0.0, 1.0]
    return p


def _write_replica(root, n=3, h=34, w=60, ext="jpg", depth_value=13107):
    import imageio.v3 as iio

    (root / "results").mkdir(parents=True)
    for i in range(n):
        iio.imwrite(root / "results" / f"frame{i:06d}.{ext}", np.full((h, w, 3), 100 + 10 * i, np.uint8))
        iio.imwrite(root / "results" / f"depth{i:06d}.png", np.full((h, w), depth_value, np.uint16))
    np.savetxt(root / "traj.txt", np.stack([_pose(i).reshape(16) for i in range(n)]))
    return root


def test_replica_layout(tmp_path):
    root = _write_replica(tmp_path / "room0")
    (tmp_path / "room0_mesh.ply").write_text("placeholder")
    k = Intrinsics(30.0, 30.0, 29.5, 16.5, 34, 60)
    ds = load_dataset(root, intrinsics=k)
    assert isinstance(ds, ReplicaDataset) and len(ds) == 3 and ds.name == "room0"
    assert ds.gt_mesh_path == tmp_path / "room0_mesh.ply"
    f = ds[2]
    assert torch.allclose(f.depth, torch.full((34, 60), 2.0))  # 13107 / 6553.5
    assert abs(float(f.color[0, 0, 0]) - 120 / 255) < 0.02  # jpeg
    torch.testing.assert_close(f.pose, torch.tensor(_pose(2), dtype=torch.float32))
    assert f.timestamp == pytest.approx(2 / 30)
    # negative index and stride
    assert ds[-1].index == 2
    assert [round(t * 30) for t in ReplicaDataset(root, intrinsics=k, stride=2).timestamps] == [0, 2]
    # crop edge updates intrinsics and images
    c = ReplicaDataset(root, intrinsics=k, crop_edge=2)
    assert c.intrinsics == Intrinsics(30.0, 30.0, 27.5, 14.5, 30, 56) and c[0].depth.shape == (30, 56)
    # default camera is NICE-SLAM's, so 34x60 depth does not fit it
    with pytest.raises(SlamInputError, match="depth image is 34x60, expected 680x1200"):
        ReplicaDataset(root)[0]
    assert REPLICA_INTRINSICS.K[0, 2] == pytest.approx(599.5)


def test_replica_png_colour_and_resize(tmp_path):
    root = _write_replica(tmp_path / "s", ext="png")
    k = Intrinsics(30.0, 30.0, 29.5, 16.5, 34, 60)
    ds = ReplicaDataset(root, intrinsics=k, crop_size=(17, 30))
    assert ds.intrinsics == Intrinsics(15.0, 15.0, 14.75, 8.25, 17, 30)
    f = ds[1]
    assert f.color.shape == (17, 30, 3) and f.depth.shape == (17, 30)
    assert float(f.color[5, 5, 1]) == pytest.approx(110 / 255, abs=1e-6)


def test_replica_bad_inputs(tmp_path):
    k = Intrinsics(30.0, 30.0, 29.5, 16.5, 34, 60)
    root = _write_replica(tmp_path / "a")
    (root / "results" / "depth000002.png").unlink()
    with pytest.raises(SlamInputError, match="3 colour images .* but 2 depth images"):
        ReplicaDataset(root, intrinsics=k)
    root = _write_replica(tmp_path / "b")
    lines = (root / "traj.txt").read_text().splitlines()
    (root / "traj.txt").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(SlamInputError, match="traj.txt: 2 poses but 3 frames"):
        ReplicaDataset(root, intrinsics=k)
    bad = np.stack([_pose(i).reshape(16) for i in range(3)])
    bad[1, 0] = 3.0  # scaled rotation
    np.savetxt(root / "traj.txt", bad)
    with pytest.raises(SlamInputError, match="traj.txt: pose 1 is not a rigid transform"):
        ReplicaDataset(root, intrinsics=k)
    bad[1, 0] = np.nan
    np.savetxt(root / "traj.txt", bad)
    with pytest.raises(SlamInputError, match="traj.txt: pose 1 contains NaN"):
        ReplicaDataset(root, intrinsics=k)
    root = _write_replica(tmp_path / "d")
    (root / "results" / "depth000001.png").rename(root / "results" / "depth000007.png")
    with pytest.raises(SlamInputError, match="frame000001.jpg is paired with depth000002.png"):
        ReplicaDataset(root, intrinsics=k)
    root = _write_replica(tmp_path / "c")
    (root / "results" / "frame000001.jpg").write_bytes(b"not an image")
    with pytest.raises(SlamInputError, match="frame000001.jpg: cannot read colour image"):
        ReplicaDataset(root, intrinsics=k)[1]
    with pytest.raises(SlamInputError, match="no results/ directory"):
        ReplicaDataset(tmp_path / "nothing")


def _write_scannet(root, n=4, bad_pose=2, color_hw=(60, 80), depth_hw=(24, 32)):
    import imageio.v3 as iio

    for sub in ("color", "depth", "pose", "intrinsic"):
        (root / sub).mkdir(parents=True)
    for i in range(n):
        img = np.zeros(color_hw + (3,), np.uint8)
        img[:, : color_hw[1] // 2] = 255  # left half white
        iio.imwrite(root / "color" / f"{i}.jpg", img, quality=100)
        iio.imwrite(root / "depth" / f"{i}.png", np.full(depth_hw, 1500, np.uint16))
        pose = np.full((4, 4), -np.inf) if i == bad_pose else _pose(i)
        np.savetxt(root / "pose" / f"{i}.txt", pose)
    kd = np.eye(4)
    kd[0, 0], kd[1, 1], kd[0, 2], kd[1, 2] = 28.9, 28.9, 15.9, 12.1
    np.savetxt(root / "intrinsic" / "intrinsic_depth.txt", kd)
    return root


def test_scannet_layout(tmp_path):
    root = _write_scannet(tmp_path / "scene0000_00")
    ds = load_dataset(root)
    assert isinstance(ds, ScanNetDataset) and len(ds) == 4
    assert ds.intrinsics == Intrinsics(28.9, 28.9, 15.9, 12.1, 24, 32)
    f = ds[1]
    assert f.color.shape == (24, 32, 3) and f.depth.shape == (24, 32)  # colour resized to the depth size
    assert float(f.color[12, 4, 0]) > 0.95 and float(f.color[12, 28, 0]) < 0.05
    assert torch.allclose(f.depth, torch.full((24, 32), 1.5))
    assert f.has_valid_pose and not ds[2].has_valid_pose
    assert torch.isnan(ds[2].pose).all()
    assert ds.valid_poses.tolist() == [True, True, False, True]
    cropped = ScanNetDataset(root, crop_edge=2)
    assert cropped.intrinsics == Intrinsics(28.9, 28.9, 13.9, 10.1, 20, 28)
    assert cropped[0].color.shape == (20, 28, 3)


def test_scannet_bad_inputs(tmp_path):
    root = _write_scannet(tmp_path / "a")
    (root / "depth" / "3.png").unlink()
    with pytest.raises(SlamInputError, match="4 colour images but 3 depth images"):
        ScanNetDataset(root)
    root = _write_scannet(tmp_path / "b")
    (root / "pose" / "1.txt").unlink()
    with pytest.raises(SlamInputError, match="no pose file for frame 1"):
        ScanNetDataset(root)
    root = _write_scannet(tmp_path / "c")
    (root / "pose" / "0.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(SlamInputError, match="0.txt: expected a 4x4 matrix"):
        ScanNetDataset(root)
