"""Users' own cameras: the TUM writer's layout read back by TUMDataset, calibration files and options."""

import numpy as np
import pytest
import torch

from slam.data import Intrinsics, TUMDataset, detect_layout
from slam.data.calibration import read_calibration, write_calibration
from slam.data.tum_writer import TUMWriter
from slam.errors import SlamInputError

K = Intrinsics(50.0, 51.0, 31.5, 23.5, 48, 64)


def _pose(i):
    c, s = np.cos(0.05 * i), np.sin(0.05 * i)
    p = np.eye(4)
    p[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    p[:3, 3] = [0.02 * i, -0.01 * i, 1.5]
    return p


def _frames(n=5, seed=0):
    rng = np.random.default_rng(seed)
    for i in range(n):
        color = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        depth = rng.uniform(0.5, 3.0, (48, 64)).astype(np.float32)
        depth[:4, :4] = np.nan       # a hole
        depth[10, 10] = 0.0          # no measurement
        depth[11, 11] = 70.0         # past the 16-bit range at 1000 / m
        yield 100.0 + i / 30, color, depth


def _record(root, n=5, poses=True, **kw):
    frames = list(_frames(n))
    with TUMWriter(root, K, depth_scale=1000.0, **kw) as rec:
        for i, (t, color, depth) in enumerate(frames):
            rec.add(t, color, depth, depth_timestamp=t + 0.004, pose=_pose(i) if poses else None)
    return frames


def test_writer_layout_reads_back_exactly(tmp_path):
    root = tmp_path / "desk"
    frames = _record(root)
    assert detect_layout(root) == "tum"
    assert (root / "rgb.txt").read_text().splitlines()[:4] == [
        "# color images", "# file: 'desk'", "# timestamp filename", "100.000000 rgb/100.000000.png"]
    assert (root / "associations.txt").read_text().splitlines()[1] == \
        "100.033333 rgb/100.033333.png 100.037333 depth/100.037333.png"
    assert (root / "calibration.yaml").read_text().splitlines()[2:] == [
        "fx: 50.0", "fy: 51.0", "cx: 31.5", "cy: 23.5", "width: 64", "height: 48", "depth_scale: 1000.0"]
    assert len((root / "groundtruth.txt").read_text().splitlines()) == 3 + 5

    ds = TUMDataset(root, relative_to_first=False)
    assert len(ds) == 5 and ds.camera == "file" and ds.calibration_file == root / "calibration.yaml"
    assert ds.intrinsics == K and ds.distortion is None and ds.depth_scale == 1000.0
    np.testing.assert_allclose(ds.timestamps, [t for t, _, _ in frames], atol=1e-6)
    for i, (_, color, depth) in enumerate(frames):
        f = ds[i]
        torch.testing.assert_close(f.color, torch.from_numpy(color).float() / 255, atol=1e-6, rtol=0)
        mm = np.rint(np.nan_to_num(depth.astype(np.float64)) * 1000)
        expected = np.where(np.isfinite(depth) & (mm <= 65535), mm, 0)
        np.testing.assert_array_equal(np.rint(f.depth.numpy().astype(np.float64) * 1000), expected)
        assert float(f.depth[0, 0]) == 0 and float(f.depth[10, 10]) == 0 and float(f.depth[11, 11]) == 0
        assert abs(float(f.depth[20, 30]) - float(depth[20, 30])) <= 0.0005  # 1 mm steps
        np.testing.assert_allclose(f.pose.double().numpy(), _pose(i), atol=1e-6)
    # poses relative to the first frame by default, as for the TUM benchmark
    torch.testing.assert_close(TUMDataset(root).gt_poses[0], torch.eye(4), atol=1e-6, rtol=0)


def test_recording_without_ground_truth_loads_with_unknown_poses(tmp_path):
    root = tmp_path / "mine"
    _record(root, n=3, poses=False)
    assert not (root / "groundtruth.txt").exists()
    ds = TUMDataset(root)
    assert len(ds) == 3 and ds.gt_file is None
    assert not bool(ds.valid_poses.any()) and torch.isnan(ds[1].pose).all()
    assert float(ds[1].depth[20, 30]) > 0.5


def test_writer_refuses_bad_frames_and_an_existing_recording(tmp_path):
    root = tmp_path / "r"
    _record(root, n=2)
    with pytest.raises(SlamInputError, match="already holds a recording"):
        TUMWriter(root, K)
    rec = TUMWriter(tmp_path / "s", K)
    with pytest.raises(SlamInputError, match=r"colour frame must be \[48, 64, 3\] uint8, got \[48, 64, 4\] uint8"):
        rec.add(0.0, np.zeros((48, 64, 4), np.uint8), np.zeros((48, 64), np.uint16))
    with pytest.raises(SlamInputError, match=r"depth frame must be \[48, 64\] \(registered to colour\), "
                                             r"got \[24, 32\]"):
        rec.add(0.0, np.zeros((48, 64, 3), np.uint8), np.zeros((24, 32), np.uint16))
    rec.add(1.0, np.zeros((48, 64, 3), np.uint8), np.full((48, 64), 1234, np.uint16))
    with pytest.raises(SlamInputError, match="timestamps must increase: 0.500000 after 1.000000"):
        rec.add(0.5, np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.uint16))
    with pytest.raises(SlamInputError, match="a pose with every frame or with none"):
        rec.add(2.0, np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.uint16), pose=np.eye(4))
    rec.close()
    assert float(TUMDataset(tmp_path / "s")[0].depth[0, 0]) == pytest.approx(1.234)  # uint16 written as is


def _folder_with_calibration(tmp_path, text=None, **calib):
    root = tmp_path / "cam"
    _record(root, n=3)
    if text is not None:
        (root / "calibration.yaml").write_text(text)
    elif calib:
        write_calibration(root / "calibration.yaml", calib.pop("intrinsics", K), **calib)
    return root


def test_precedence_options_over_calibration_file_over_folder_name(tmp_path):
    root = _folder_with_calibration(tmp_path, distortion=[0.1, -0.2, 0.001, 0.002, 0.05], depth_scale=1000.0)
    ds = TUMDataset(root, undistort=False)
    assert ds.camera == "file" and ds.raw_intrinsics == K and ds.distortion is None  # undistort=False
    ds = TUMDataset(root)
    assert ds.distortion == (0.1, -0.2, 0.001, 0.002, 0.05) and ds._grid is not None
    # explicit intrinsics (a mapping, as from data.options): the size defaults to the images', no distortion
    ds = TUMDataset(root, intrinsics={"fx": 40, "fy": 41, "cx": 32, "cy": 24})
    assert ds.camera == "custom" and ds.intrinsics == Intrinsics(40.0, 41.0, 32.0, 24.0, 48, 64)
    assert ds.distortion is None and ds.depth_scale == 1000.0  # the depth scale is the sensor's: still the file's
    ds = TUMDataset(root, intrinsics={"fx": 40, "fy": 41, "cx": 32, "cy": 24}, distortion=[0.01, 0, 0, 0])
    assert ds.distortion == (0.01, 0.0, 0.0, 0.0)
    # an explicit depth scale beats the file's
    base = TUMDataset(root)
    half = TUMDataset(root, depth_scale=2000.0)
    torch.testing.assert_close(half[0].depth * 2, base[0].depth)
    # a named camera beats the file: fr1 is for 640x480 images
    with pytest.raises(SlamInputError, match=r"expected 480x640 \(the image size in the fr1 calibration"):
        TUMDataset(root, camera="fr1")
    # another calibration file, relative to the folder
    write_calibration(root / "other.yaml", Intrinsics(60.0, 60.0, 32.0, 24.0, 48, 64), depth_scale=500.0)
    ds = TUMDataset(root, calibration="other.yaml")
    assert ds.intrinsics.fx == 60.0 and ds.depth_scale == 500.0 and ds.calibration_file == root / "other.yaml"
    # from a config: data.options is passed to the loader as it is
    from slam.config import load_config
    from slam.engine.setup import load_data

    cfg = load_config("tum", [f"data.path={root}", "data.options.intrinsics={fx: 45, fy: 45, cx: 31.5, cy: 23.5}",
                              "data.options.crop_size=null", "data.options.crop_edge=0",
                              "data.options.depth_scale=4000"], profile="paper")
    ds = load_data(cfg)
    assert ds.intrinsics == Intrinsics(45.0, 45.0, 31.5, 23.5, 48, 64) and ds.depth_scale == 4000.0


BASE = "fx: 50\nfy: 51\ncx: 31.5\ncy: 23.5\nwidth: 64\nheight: 48\n"


@pytest.mark.parametrize(("text", "message"), [
    (BASE.replace("cy: 23.5\n", ""), r"calibration.yaml: missing key 'cy' \(needs fx, fy, cx, cy, width, height\)"),
    (BASE.replace("fx: 50", "fx: fifty"), r"calibration.yaml: key 'fx' must be a number, got 'fifty'"),
    (BASE.replace("fy: 51", "fy: .nan"), r"calibration.yaml: key 'fy' must be finite, got nan"),
    (BASE.replace("fx: 50", "fx: -50"), r"calibration.yaml: key 'fx' must be positive, got -50.0"),
    (BASE.replace("width: 64", "width: 80"), r"cam/depth/100.004000.png: depth image is 48x64, expected 48x80 "
                                             r"\(the image size in .*cam/calibration.yaml, keys height and width\)"),
    (BASE.replace("height: 48", "height: 47.5"), r"key 'height' must be a positive whole number of pixels"),
    (BASE + "distortion: [0.1, 0.2]\n", r"key 'distortion' must be a list \[k1, k2, p1, p2, k3\] \(4 or 5 numbers\)"),
    (BASE + "distortion: [0.1, x, 0, 0]\n", r"key 'distortion\[1\]' must be a number, got 'x'"),
    (BASE + "depth_scale: 0\n", r"key 'depth_scale' must be positive"),
    (BASE + "focal: 50\n", r"calibration.yaml: unknown key 'focal'"),
    ("fx: [50\n", r"calibration.yaml: invalid YAML"),
    ("- 50\n- 51\n", r"calibration.yaml: expected a mapping with keys fx, fy, cx, cy, width, height, got list"),
])
def test_bad_calibration_file_names_the_file_and_key(tmp_path, text, message):
    root = _folder_with_calibration(tmp_path, text=text)
    with pytest.raises(SlamInputError, match=message):
        TUMDataset(root)


def test_calibration_numbers_in_exponent_notation_and_bad_options(tmp_path):
    root = _folder_with_calibration(tmp_path, text=BASE + "distortion: [1e-3, -2E-4, 0, 0, 0]\ndepth_scale: 1e3\n")
    cal = read_calibration(root / "calibration.yaml")
    assert cal.distortion == (1e-3, -2e-4, 0.0, 0.0, 0.0) and cal.depth_scale == 1000.0
    with pytest.raises(SlamInputError, match=r"cam: option 'intrinsics': key 'fx' must be a number, got 'x'"):
        TUMDataset(root, intrinsics={"fx": "x", "fy": 1, "cx": 1, "cy": 1})
    with pytest.raises(SlamInputError, match=r"option 'intrinsics': missing key 'cx' \(needs fx, fy, cx, cy\)"):
        TUMDataset(root, intrinsics={"fx": 1, "fy": 1})
    with pytest.raises(SlamInputError, match=r"option 'intrinsics': give both 'width' and 'height' or neither"):
        TUMDataset(root, intrinsics={"fx": 1, "fy": 1, "cx": 1, "cy": 1, "width": 64})
    with pytest.raises(SlamInputError, match=r"option 'depth_scale': key 'depth_scale' must be a number"):
        TUMDataset(root, depth_scale="deep")
    with pytest.raises(SlamInputError, match=r"nope.yaml: calibration file not found"):
        TUMDataset(root, calibration="nope.yaml")


@pytest.mark.slow
def test_lrslam_runs_on_a_recording_without_ground_truth(tiny_seq, tmp_path, capsys):
    """The RealSense workflow minus the camera: frames -> TUMWriter -> `lrslam run --config tum`."""
    import json

    from slam.cli import main
    from slam.data import load_dataset

    from tests.slam.conftest import TINY

    src = load_dataset(tiny_seq)
    root = tmp_path / "my_room"
    with TUMWriter(root, src.intrinsics, depth_scale=1000.0) as rec:
        for i in range(8):
            f = src[i]
            rec.add(f.timestamp, (f.color.numpy() * 255).round().astype(np.uint8), f.depth.numpy())
    out = tmp_path / "run"
    rc = main(["run", "--config", "tum", "--data", str(root), "--out", str(out), "--quiet", "--no-mesh", *TINY,
               "data.options.crop_size=null", "data.options.crop_edge=0", "tracking.ignore_edge=[4,4]"])
    assert rc == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["num_frames"] == 6
    traj = np.loadtxt(out / "trajectory.txt")
    assert traj.shape == (6, 8) and np.isfinite(traj).all()
    np.testing.assert_allclose(traj[:, 0], [src.timestamps[i] for i in range(6)], atol=1e-6)
