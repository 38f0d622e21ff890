"""7-Scenes: tiny sequence folders written in its layout, read back; bad input names the file."""

import json

import numpy as np
import pytest

from slam.data import Intrinsics, SevenScenesDataset, detect_layout, load_dataset
from slam.errors import SlamInputError

# a 64x48 camera with the Kinect's field of view (585 px on 640)
SMALL = {"fx": 58.5, "fy": 58.5, "cx": 32.0, "cy": 24.0, "width": 64, "height": 48}


def _pose(i):
    c, s = np.cos(0.04 * i), np.sin(0.04 * i)
    p = np.eye(4)
    p[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    p[:3, 3] = [0.01 * i, 0.5, -0.02 * i]
    return p


def _write_pose(path, m):
    # the dataset's own spelling: tab-separated exponent notation with a trailing tab
    path.write_text("".join("\t".join(f"{v:.7e}" for v in row) + "\t\n" for row in m))


def _write_7scenes(root, n=4, h=48, w=64, ext="png", first=0):
    import imageio.v3 as iio

    root.mkdir(parents=True)
    for i in range(first, first + n):
        stem = root / f"frame-{i:06d}"
        iio.imwrite(f"{stem}.color.{ext}", np.full((h, w, 3), 30 * i + 20, np.uint8))
        depth = np.full((h, w), 1000 + 100 * i, np.uint16)
        depth[:3, :3] = 65535   # no measurement
        depth[h - 1, w - 1] = 0
        iio.imwrite(f"{stem}.depth.png", depth)
        _write_pose(root / f"frame-{i:06d}.pose.txt", _pose(i))
    return root


def test_layout_reads_back(tmp_path):
    root = _write_7scenes(tmp_path / "chess" / "seq-01", first=3)
    assert detect_layout(root) == "7scenes"
    ds = load_dataset(root, intrinsics=SMALL)
    assert isinstance(ds, SevenScenesDataset) and ds.name == "chess/seq-01" and len(ds) == 4
    assert ds.intrinsics == Intrinsics(58.5, 58.5, 32.0, 24.0, 48, 64) and ds.depth_scale == 1000.0
    assert ds.timestamps == pytest.approx([3 / 30, 4 / 30, 5 / 30, 6 / 30])
    assert ds.gt_mesh_path is None and bool(ds.valid_poses.all())
    for k in range(4):
        f = ds[k]
        i = k + 3
        assert f.color.shape == (48, 64, 3) and f.color[10, 10, 0] == pytest.approx((30 * i + 20) / 255)
        assert float(f.depth[20, 20]) == pytest.approx(1.0 + 0.1 * i)
        assert float(f.depth[:3, :3].abs().max()) == 0.0 and float(f.depth[47, 63]) == 0.0  # 65535 and 0
        assert int((f.depth == 0).sum()) == 10
        np.testing.assert_allclose(f.pose.double().numpy(), _pose(i), atol=1e-6)  # as stored: no axis change


def test_default_kinect_camera_resize_and_jpg_colour(tmp_path):
    root = _write_7scenes(tmp_path / "heads" / "seq-02", n=2, h=480, w=640, ext="jpg")
    ds = SevenScenesDataset(root)
    assert ds.raw_intrinsics == Intrinsics(585.0, 585.0, 320.0, 240.0, 480, 640)
    ds = SevenScenesDataset(root, crop_size=(240, 320), crop_edge=4)
    assert ds.intrinsics == Intrinsics(292.5, 292.5, 156.0, 116.0, 232, 312)
    f = ds[1]
    assert f.color.shape == (232, 312, 3) and f.depth.shape == (232, 312)
    assert abs(float(f.color[100, 100, 1]) - 50 / 255) < 3 / 255  # JPEG
    # the 3x3 block of 65535 is 1.5 px after halving: still no measurement, not 65.5 m
    small = SevenScenesDataset(root, crop_size=(240, 320))[0].depth
    assert float(small[:2, :2].max()) == 0.0 and float(small.max()) == pytest.approx(1.0)


def test_bad_inputs_name_the_file(tmp_path):
    def fresh(name, **kw):
        return _write_7scenes(tmp_path / name / "seq-01", **kw)

    root = fresh("a")
    (root / "frame-000002.pose.txt").unlink()
    with pytest.raises(SlamInputError, match=r"a/seq-01/frame-000002.pose.txt: pose file not found "
                                             r"\(1 of 4 colour frames have no pose file\)"):
        SevenScenesDataset(root, intrinsics=SMALL)
    root = fresh("b")
    (root / "frame-000001.depth.png").unlink()
    with pytest.raises(SlamInputError, match=r"b/seq-01/frame-000001.depth.png: depth file not found"):
        SevenScenesDataset(root, intrinsics=SMALL)
    root = fresh("c")
    (root / "frame-000003.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    with pytest.raises(SlamInputError, match=r"frame-000003.pose.txt: expected a 4x4 matrix \(4 lines of 4 "
                                             r"numbers\), got 3 lines of \[4\] numbers"):
        SevenScenesDataset(root, intrinsics=SMALL)
    m = _pose(1)
    m[0, 3] = np.nan
    _write_pose(root / "frame-000003.pose.txt", m)
    with pytest.raises(SlamInputError, match=r"frame-000003.pose.txt: pose contains NaN or inf"):
        SevenScenesDataset(root, intrinsics=SMALL)
    _write_pose(root / "frame-000003.pose.txt", np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(SlamInputError, match=r"frame-000003.pose.txt: not a rigid camera-to-world transform "
                                             r"\(\|R\^T R - I\| = 3, det R = 8.0000"):
        SevenScenesDataset(root, intrinsics=SMALL)
    (root / "frame-000003.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 zero\n0 0 0 1\n")
    with pytest.raises(SlamInputError, match=r"frame-000003.pose.txt: non-numeric value in the pose"):
        SevenScenesDataset(root, intrinsics=SMALL)
    (root / "frame-000003.pose.txt").write_text("")
    with pytest.raises(SlamInputError, match=r"frame-000003.pose.txt: expected a 4x4 matrix .*got an empty file"):
        SevenScenesDataset(root, intrinsics=SMALL)


def test_mixed_sizes_and_wrong_images_name_the_file(tmp_path):
    import imageio.v3 as iio

    root = _write_7scenes(tmp_path / "d" / "seq-01")
    iio.imwrite(root / "frame-000002.depth.png", np.full((24, 32), 1000, np.uint16))
    ds = SevenScenesDataset(root, intrinsics=SMALL)
    ds[1]
    with pytest.raises(SlamInputError, match=r"frame-000002.depth.png: depth image is 24x32, expected 48x64"):
        ds[2]
    iio.imwrite(root / "frame-000002.depth.png", np.full((48, 64), 10, np.uint8))
    with pytest.raises(SlamInputError, match=r"frame-000002.depth.png: expected a 16-bit depth PNG"):
        ds[2]
    iio.imwrite(root / "frame-000003.color.png", np.zeros((24, 32, 3), np.uint8))
    with pytest.raises(SlamInputError, match=r"frame-000003.color.png: colour image is 24x32, expected 48x64"):
        ds[3]
    # the first frame decides: the Kinect camera is 640x480
    with pytest.raises(SlamInputError, match=r"frame-000000.depth.png: depth image is 48x64, expected 480x640"):
        SevenScenesDataset(root)
    iio.imwrite(root / "frame-000001.color.jpg", np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(SlamInputError, match=r"frame 1 has both frame-000001.color"):
        SevenScenesDataset(root, intrinsics=SMALL)


def test_layout_detection(tmp_path):
    scene = tmp_path / "fire"
    _write_7scenes(scene / "seq-01", n=1)
    _write_7scenes(scene / "seq-02", n=1)
    with pytest.raises(SlamInputError, match=r"fire: a 7-Scenes scene with 2 sequences; pass one sequence folder, "
                                             r"e.g. .*fire/seq-01"):
        detect_layout(scene)
    with pytest.raises(SlamInputError, match=r", 7-Scenes frame-NNNNNN\.color\.png/\.depth\.png/\.pose\.txt, "
                                             r"or a ROS bag \(a ROS 1 \.bag file, or a ROS 2 folder of "
                                             r"metadata\.yaml and \.db3/\.mcap files\)\)$"):
        detect_layout(tmp_path)


def test_preset_loads_and_validates():
    from slam.config import load_config, list_presets

    cfg = load_config("7scenes", profile="quality")
    assert "7scenes" in list_presets() and cfg.name == "7scenes"
    assert cfg.data.kind == "7scenes" and cfg.data.options == {"crop_size": [240, 320], "crop_edge_raw": 8,
                                                               "focal_px": 207}
    assert (cfg.rendering.n_stratified, cfg.rendering.n_importance) == (16, 8)
    assert (cfg.tracking.iters, cfg.tracking.pixels, cfg.mapping.every_frame, cfg.mapping.keyframe_every) == (20, 400, 1, 1)
    assert cfg.scene.bound == "auto" and cfg.representation == "lrslam"


def _synthetic_as_7scenes(tiny_seq, root, n=8):
    """The tiny synthetic room (Replica layout, 60x80) rewritten in the 7-Scenes layout."""
    import imageio.v3 as iio

    src = load_dataset(tiny_seq)
    root.mkdir(parents=True)
    for i in range(n):
        f = src[i]
        stem = root / f"frame-{i:06d}"
        iio.imwrite(f"{stem}.color.png", (f.color.numpy() * 255).round().astype(np.uint8))
        mm = np.rint(f.depth.numpy().astype(np.float64) * 1000)
        iio.imwrite(f"{stem}.depth.png", np.where(mm > 0, mm, 65535).astype(np.uint16))
        _write_pose(root / f"frame-{i:06d}.pose.txt", f.pose.double().numpy())
    k = src.intrinsics
    return f"data.options.intrinsics={{fx: {k.fx}, fy: {k.fy}, cx: {k.cx}, cy: {k.cy}, width: {k.width}, " \
           f"height: {k.height}}}"


@pytest.mark.slow
def test_lrslam_run_with_the_preset(tiny_seq, tmp_path, capsys):
    from slam.cli import main
    from tests.slam.conftest import TINY

    root = tmp_path / "room" / "seq-01"
    camera = _synthetic_as_7scenes(tiny_seq, root)
    args = ["run", "--config", "7scenes", "--data", str(root), "--quiet", "--no-mesh", *TINY, camera,
            "data.options.crop_size=null", "data.options.crop_edge=0", "tracking.ignore_edge=[4,4]", "--profile", "quality"]
    out = tmp_path / "run"
    assert main([*args, "--out", str(out)]) == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["num_frames"] == 6 and m["ate_rmse_m"] is not None and m["ate_rmse_m"] < 0.1
    gt = np.loadtxt(out / "trajectory_gt.txt")
    np.testing.assert_allclose(gt[:, 0], np.arange(6) / 30, atol=1e-6)
    capsys.readouterr()
    # a pose file missing: one line, exit 2
    (root / "frame-000004.pose.txt").unlink()
    assert main([*args, "--out", str(tmp_path / "run2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("lrslam run: error: ")
    assert "room/seq-01/frame-000004.pose.txt: pose file not found" in err
