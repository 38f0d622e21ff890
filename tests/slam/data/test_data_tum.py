import numpy as np
import pytest
import torch

from slam.data import REFERENCE_OPTIONS, Intrinsics, TUMDataset, load_dataset
from slam.data.base import undistort_grid
from slam.errors import SlamInputError


@pytest.fixture(scope="module")
def rpy(shared_data):
    path = shared_data / "tum_fr1_rpy"
    if not path.is_dir():
        pytest.skip("tum_fr1_rpy excerpt missing")
    return path


def test_real_excerpt_loads(rpy):
    ds = load_dataset(rpy)
    assert isinstance(ds, TUMDataset) and ds.camera == "fr1"
    assert len(ds) == 100
    assert ds.timestamps[0] == pytest.approx(1305031233.693779)
    assert ds.timestamps[-1] == pytest.approx(1305031236.993680)
    assert ds.intrinsics == Intrinsics(517.3, 516.5, 318.6, 255.3, 480, 640)
    assert ds.distortion == (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    f = ds[0]
    assert f.color.shape == (480, 640, 3) and f.color.dtype == torch.float32
    assert 0.0 <= float(f.color.min()) and float(f.color.max()) <= 1.0
    assert f.depth.shape == (480, 640) and f.depth.dtype == torch.float32
    valid = f.depth[f.depth > 0]
    assert 0.57 <= float(valid.min()) and float(valid.max()) <= 3.85
    assert 0.75 < valid.numel() / f.depth.numel() < 0.85
    # default: poses relative to the first frame
    torch.testing.assert_close(f.pose, torch.eye(4), atol=1e-6, rtol=0)
    # excerpt: ~0.31 m path, mean 1.44 deg/frame
    p = ds.gt_poses.double().numpy()
    rel = np.einsum("nji,njk->nik", p[:-1, :3, :3], p[1:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert ang.mean() == pytest.approx(1.44, abs=0.1) and ang.max() < 2.9
    path_len = np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1).sum()
    assert 0.2 < path_len < 0.4


def test_real_excerpt_absolute_poses_and_timestamp_association(rpy):
    a = TUMDataset(rpy, relative_to_first=False)
    b = TUMDataset(rpy, association="timestamps", relative_to_first=False)
    assert len(b) == 100
    np.testing.assert_allclose(a.timestamps, b.timestamps)
    assert [p.name for p in a.depth_paths] == [p.name for p in b.depth_paths]
    # frame 0 lies between GT rows 1305031233.6931 and .7031 of groundtruth.txt
    t = a.gt_poses[0, :3, 3].double().numpy()
    np.testing.assert_allclose(t, [1.2758, 0.6109, 1.5190], atol=2e-3)
    R = a.gt_poses[0, :3, :3].double()
    torch.testing.assert_close(R.T @ R, torch.eye(3, dtype=torch.float64), atol=1e-6, rtol=0)
    # nearest-sample GT is within a few mm of the interpolated one
    c = TUMDataset(rpy, interpolate_gt=False, relative_to_first=False)
    assert float((c.gt_poses[:, :3, 3] - a.gt_poses[:, :3, 3]).norm(dim=1).max()) < 0.01


def test_reference_crop_matches_eslam_working_intrinsics(rpy):
    ds = TUMDataset(rpy, **REFERENCE_OPTIONS["tum"], max_frames=2)
    k = ds.intrinsics
    assert (k.height, k.width) == (368, 496)
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((413.84, 413.2, 246.88, 196.24))
    f = ds[1]
    assert f.color.shape == (368, 496, 3) and f.depth.shape == (368, 496)
    assert len(ds) == 2


def test_undistortion_moves_a_point_to_its_undistorted_pixel():
    k = Intrinsics(517.3, 516.5, 318.6, 255.3, 480, 640)
    dist = (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    grid = undistort_grid(k, dist)
    # the undistorted pixel (100, 80) samples the distorted image at grid[80, 100]
    g = grid[0, 80, 100].double()
    ud = (g[0] + 1) / 2 * 639
    vd = (g[1] + 1) / 2 * 479
    x, y = (100 - 318.6) / 517.3, (80 - 255.3) / 516.5
    r2 = x * x + y * y
    rad = 1 + 0.2624 * r2 - 0.9531 * r2**2 + 1.1633 * r2**3
    xd = x * rad + 2 * -0.0054 * x * y + 0.0026 * (r2 + 2 * x * x)
    yd = y * rad + -0.0054 * (r2 + 2 * y * y) + 2 * 0.0026 * x * y
    assert float(ud) == pytest.approx(xd * 517.3 + 318.6, abs=1e-3)
    assert float(vd) == pytest.approx(yd * 516.5 + 255.3, abs=1e-3)
    # the principal point does not move
    c = grid[0, 255, 318].double()
    assert float((c[0] + 1) / 2 * 639) == pytest.approx(318.0, abs=0.05)


# ---------------------------------------------------------------- tiny sequences in the native layout
def _write_tum(root, n=5, depth_value=5000, depth_shape=(24, 32), depth_dtype=np.uint16, gt_shift=0.0,
               assoc=False, nan_gt=False):
    import imageio.v3 as iio

    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    t0 = 1000.0
    rgb_lines, depth_lines, assoc_lines = ["# color images"], ["# depth"], []
    for i in range(n):
        tr, td = t0 + i / 30, t0 + i / 30 + 0.01
        img = np.full((24, 32, 3), 40 * i, np.uint8)
        iio.imwrite(root / "rgb" / f"{tr:.6f}.png", img)
        iio.imwrite(root / "depth" / f"{td:.6f}.png", np.full(depth_shape, depth_value, depth_dtype))
        rgb_lines.append(f"{tr:.6f} rgb/{tr:.6f}.png")
        depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
        assoc_lines.append(f"{tr:.6f} rgb/{tr:.6f}.png {td:.6f} depth/{td:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if assoc:
        (root / "associations.txt").write_text("\n".join(assoc_lines) + "\n")
    gt = ["# timestamp tx ty tz qx qy qz qw"]
    for k in range(int(n / 30 * 100) + 30):
        t = t0 - 0.1 + gt_shift + k * 0.01
        x = "nan" if nan_gt and k == 12 else f"{0.1 * (t - t0):.6f}"
        gt.append(f"{t:.4f} {x} 0.0 1.0 0 0 0 1")
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return root


def test_tiny_tum_layout(tmp_path):
    root = _write_tum(tmp_path / "rgbd_dataset_freiburg3_tiny")
    ds = load_dataset(root, intrinsics=Intrinsics(30, 30, 15.5, 11.5, 24, 32), relative_to_first=False)
    assert len(ds) == 5 and ds.camera == "custom"
    f = ds[2]
    assert torch.all(f.depth == 1.0)  # 5000 / 5000
    assert f.color[0, 0, 0] == pytest.approx(80 / 255)
    # GT x = 0.1 * (t - t0), interpolated at the rgb time
    assert float(f.pose[0, 3]) == pytest.approx(0.1 * 2 / 30, abs=1e-5)
    assert float(f.pose[2, 3]) == pytest.approx(1.0)
    # the folder name says fr3, whose calibration is for 640x480: the 32x24 images need their own camera
    with pytest.raises(SlamInputError, match=r"depth/1000.010000.png: depth image is 24x32, expected 480x640 "
                                             r"\(the image size in the fr3 calibration; another camera needs "
                                             r".*rgbd_dataset_freiburg3_tiny/calibration.yaml\)"):
        TUMDataset(root, max_frames=3)


def test_tum_bad_inputs(tmp_path):
    k = Intrinsics(30, 30, 15.5, 11.5, 24, 32)
    # ground truth far from the images: empty association
    root = _write_tum(tmp_path / "a", gt_shift=100.0)
    with pytest.raises(SlamInputError, match="empty association"):
        TUMDataset(root, intrinsics=k)
    # depth of the wrong size
    root = _write_tum(tmp_path / "b", depth_shape=(12, 16))
    with pytest.raises(SlamInputError, match=r"depth image is 12x16, expected 24x32"):
        TUMDataset(root, intrinsics=k)[0]
    # 8-bit depth
    root = _write_tum(tmp_path / "c", depth_dtype=np.uint8, depth_value=5)
    with pytest.raises(SlamInputError, match="16-bit depth"):
        TUMDataset(root, intrinsics=k)[0]
    # missing image listed in rgb.txt
    root = _write_tum(tmp_path / "d")
    next((root / "rgb").iterdir()).unlink()
    with pytest.raises(SlamInputError, match="image file not found"):
        TUMDataset(root, intrinsics=k)
    # NaN ground truth
    root = _write_tum(tmp_path / "e", nan_gt=True)
    with pytest.raises(SlamInputError, match="groundtruth.txt: ground-truth row 12 contains NaN"):
        TUMDataset(root, intrinsics=k)
    # empty associations.txt
    root = _write_tum(tmp_path / "f", assoc=True)
    (root / "associations.txt").write_text("# nothing\n")
    with pytest.raises(SlamInputError, match="associations.txt: empty association"):
        TUMDataset(root, intrinsics=k)
    # an own recording (no groundtruth.txt) whose depth frames are all further than max_dt from the colour ones
    root = _write_tum(tmp_path / "g")
    (root / "groundtruth.txt").unlink()
    rows = [line.split() for line in (root / "depth.txt").read_text().splitlines() if not line.startswith("#")]
    (root / "depth.txt").write_text("".join(f"{float(t) + 0.5:.6f} {f}\n" for t, f in rows))
    with pytest.raises(SlamInputError, match=r"depth.txt: empty association: no rgb frame has a depth frame within "
                                             r"0.08 s \(rgb 5 frames, no ground truth\)"):
        TUMDataset(root, intrinsics=k)
    with pytest.raises(SlamInputError, match="not a recognised dataset layout"):
        load_dataset(tmp_path)
    with pytest.raises(SlamInputError, match="not found"):
        load_dataset(tmp_path / "nope")


def test_tum_associations_file_is_used(tmp_path):
    root = _write_tum(tmp_path / "g", assoc=True, n=4)
    lines = (root / "associations.txt").read_text().splitlines()
    (root / "associations.txt").write_text("\n".join(lines[:3]) + "\n")
    ds = TUMDataset(root, intrinsics=Intrinsics(30, 30, 15.5, 11.5, 24, 32))
    assert len(ds) == 3
    assert len(TUMDataset(root, intrinsics=Intrinsics(30, 30, 15.5, 11.5, 24, 32), association="timestamps")) == 4


def test_real_groundtruth_reads_and_pairs_with_our_trajectory(rpy, tmp_path):
    from slam.eval import ate_from_files, read_tum_trajectory, write_tum_trajectory

    ts, poses = read_tum_trajectory(rpy / "groundtruth.txt")
    assert len(ts) == 431 and poses.shape == (431, 4, 4)
    ds = TUMDataset(rpy, relative_to_first=False)
    ours = write_tum_trajectory(tmp_path / "gt_at_frames.txt", ds.timestamps, ds.gt_poses.double())
    res, paired = ate_from_files(ours, rpy / "groundtruth.txt", max_dt=0.006)
    # interpolated poses vs the nearest 100 Hz mocap rows (<= 5 ms away): a few mm at most
    assert res.n == 100 and res.rmse < 0.004
