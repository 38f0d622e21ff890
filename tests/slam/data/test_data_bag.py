"""ROS bags as data (slam.data.bag): bags written here with rosbags' writers from the tiny synthetic sequence,
read back frame for frame against the folder they came from."""

from __future__ import annotations

import hashlib
import sys
from decimal import Decimal

import numpy as np
import pytest
import torch

pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from slam.core.geometry import poses_to_tum  # noqa: E402
from slam.data import BagDataset, ReplicaDataset, detect_layout, load_dataset  # noqa: E402
from slam.errors import SlamInputError  # noqa: E402

N = 8  # frames written
T0 = 1_305_031_233_693_779_000  # ns: a TUM-like clock, far from 0
DT = 33_333_333  # ns between colour frames
DEPTH_LAG = 7_000_000  # ns: depth stamped after its colour frame, as the Kinect's is

TUM_TOPICS = ("/camera/rgb/image_color", "/camera/depth/image", "/camera/rgb/camera_info")
RS_TOPICS = ("/camera/camera/color/image_raw", "/camera/camera/aligned_depth_to_color/image_raw",
             "/camera/camera/color/camera_info")
DISTORTION = (0.01, -0.02, 0.001, -0.002, 0.003)


class BagWriter:
    """One ROS 1 file or ROS 2 folder (``storage`` sqlite3 or mcap) written with rosbags' writers."""

    def __init__(self, path, ros2: bool = False, storage: str = "sqlite3"):
        self.ros2 = ros2
        self.ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self.w = Writer2(path, version=9, storage_plugin=plugin) if ros2 else Writer1(path)
        self.w.open()
        self.conns = {}

    def _header(self, ns: int):
        t = self.ts.types
        stamp = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        if self.ros2:
            return t["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")
        return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="camera")

    def write(self, topic: str, msg, ns: int, record_ns: int | None = None):
        if topic not in self.conns:
            self.conns[topic] = self.w.add_connection(topic, msg.__msgtype__, typestore=self.ts)
        serialize = self.ts.serialize_cdr if self.ros2 else self.ts.serialize_ros1
        data = serialize(msg, msg.__msgtype__)
        self.w.write(self.conns[topic], ns if record_ns is None else record_ns, data)

    def image(self, topic: str, ns: int, array: np.ndarray, encoding: str, **kw):
        h, w = array.shape[:2]
        data = np.ascontiguousarray(array).view(np.uint8).reshape(-1)
        msg = self.ts.types["sensor_msgs/msg/Image"](header=self._header(ns), height=h, width=w, encoding=encoding,
                                                     is_bigendian=0, step=data.size // h, data=data)
        self.write(topic, msg, ns, **kw)

    def compressed(self, topic: str, ns: int, rgb: np.ndarray, fmt: str):
        import imageio.v3 as iio

        data = np.frombuffer(iio.imwrite("<bytes>", rgb, extension=f".{fmt}"), dtype=np.uint8)
        msg = self.ts.types["sensor_msgs/msg/CompressedImage"](header=self._header(ns), data=data,
                                                               format=f"rgb8; {fmt} compressed bgr8")
        self.write(topic, msg, ns)

    def camera_info(self, topic: str, ns: int, intr, distortion=DISTORTION, model="plumb_bob"):
        t = self.ts.types
        k = np.array([intr.fx, 0, intr.cx, 0, intr.fy, intr.cy, 0, 0, 1], dtype=np.float64)
        p = np.array([intr.fx, 0, intr.cx, 0, 0, intr.fy, intr.cy, 0, 0, 0, 1, 0], dtype=np.float64)
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        arrays = dict(d=np.array(distortion, dtype=np.float64), k=k, r=np.eye(3).reshape(-1), p=p)
        if not self.ros2:
            arrays = {key.upper(): v for key, v in arrays.items()}
        msg = t["sensor_msgs/msg/CameraInfo"](header=self._header(ns), height=intr.height, width=intr.width,
                                              distortion_model=model, binning_x=0, binning_y=0, roi=roi, **arrays)
        self.write(topic, msg, ns)

    def close(self):
        self.w.close()


def stamp_ns(text: str) -> int:
    """A decimal time in seconds (a TUM file name's ``1305031233.693779``) as integer nanoseconds, exactly."""
    return int(Decimal(text).scaleb(9).to_integral_value())


def write_rgbd_bag(path, src, *, ros2=False, storage="sqlite3", topics=TUM_TOPICS, depth="32FC1", color="rgb8",
                   frames=N, distortion=DISTORTION, skip_depth=(), stamps=None):
    """Frames ``0..frames-1`` of the dataset ``src`` (raw images: ``raw_color`` uint8, ``raw_depth`` float32
    metres) as a bag, with one CameraInfo of its raw camera.

    Args:
        depth: 32FC1 (the metres as the source loads them, bit for bit) or 16UC1 (millimetres).
        color: an Image encoding, or ``png`` / ``jpeg`` for a CompressedImage.
        distortion: the CameraInfo's D (None: the source's distortion, zeros if none).
        skip_depth: frames written without depth.
        stamps: ``(colour, depth)`` ns per frame; default colour at ``T0 + i DT``, depth ``DEPTH_LAG`` later.
    """
    w = BagWriter(path, ros2=ros2, storage=storage)
    color_topic, depth_topic, info_topic = topics
    if stamps is None:
        stamps = [(T0 + i * DT, T0 + i * DT + DEPTH_LAG) for i in range(frames)]
    if distortion is None:
        distortion = src.distortion or (0.0,) * 5
    w.camera_info(info_topic, stamps[0][0], src.raw_intrinsics, distortion)
    for i in range(frames):
        rgb = src.raw_color(i)
        ns, depth_ns = stamps[i]
        if color in ("png", "jpeg"):
            w.compressed(color_topic, ns, rgb, color)
        else:
            w.image(color_topic, ns, {"rgb8": rgb, "bgr8": rgb[..., ::-1], "mono8": rgb[..., :1],
                                      "rgba8": np.dstack([rgb, np.full_like(rgb[..., :1], 7)])}[color], color)
        if i not in skip_depth:
            metres = src.raw_depth(i).numpy()
            raw = metres if depth == "32FC1" else np.round(metres * 1000).astype(np.uint16)
            w.image(depth_topic, depth_ns, raw, depth)
    w.close()
    return path


def write_groundtruth(path, src, frames=N):
    """The source's poses at the colour stamps as a TUM trajectory, at full precision."""
    rows = poses_to_tum(src.gt_poses[:frames].double().numpy())
    with open(path, "w") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        for i, r in enumerate(rows):
            fh.write(f"{(T0 + i * DT) / 1e9:.9f} " + " ".join(repr(float(v)) for v in r) + "\n")
    return path


@pytest.fixture(scope="module")
def bags(tiny_seq, tmp_path_factory):
    """The source dataset and the bags written from it (names in the dict)."""
    src = ReplicaDataset(tiny_seq, undistort=False)
    root = tmp_path_factory.mktemp("bags")
    out = {"src": src, "root": root}
    out["ros1"] = write_rgbd_bag(root / "tum.bag", src)
    out["gt"] = write_groundtruth(root / "groundtruth.txt", src)
    out["sqlite3"] = write_rgbd_bag(root / "rs_sqlite3", src, ros2=True, topics=RS_TOPICS, depth="16UC1")
    out["mcap"] = write_rgbd_bag(root / "rs_mcap", src, ros2=True, storage="mcap", topics=RS_TOPICS, depth="16UC1",
                                 color="bgr8")
    out["png"] = write_rgbd_bag(root / "png.bag", src, color="png", frames=3)
    out["jpeg"] = write_rgbd_bag(root / "jpeg.bag", src, ros2=True, topics=(RS_TOPICS[0] + "/compressed",
                                 *RS_TOPICS[1:]), color="jpeg", frames=3)
    out["mono"] = write_rgbd_bag(root / "mono.bag", src, color="mono8", frames=2)
    out["rgba"] = write_rgbd_bag(root / "rgba.bag", src, color="rgba8", frames=2)
    out["gap"] = write_rgbd_bag(root / "gap.bag", src, frames=5, skip_depth=(2,))
    out["no_depth"] = write_rgbd_bag(root / "no_depth.bag", src, topics=(TUM_TOPICS[0], "/camera/ir/image",
                                                                         TUM_TOPICS[2]), frames=2)
    # two colour topics: the loader cannot choose, an option does
    w = BagWriter(root / "two_colour.bag")
    w.camera_info(TUM_TOPICS[2], T0, src.raw_intrinsics)
    for i in range(2):
        w.image(TUM_TOPICS[0], T0 + i * DT, src.raw_color(i), "rgb8")
        w.image("/camera/rgb/image_rect_color", T0 + i * DT, src.raw_color(i + 2), "rgb8")
        w.image(TUM_TOPICS[1], T0 + i * DT, src.raw_depth(i).numpy(), "32FC1")
    w.close()
    out["two_colour"] = root / "two_colour.bag"
    # depth at half the colour size (not registered), and an encoding the loader does not read
    w = BagWriter(root / "half_depth.bag")
    w.camera_info(TUM_TOPICS[2], T0, src.raw_intrinsics)
    w.image(TUM_TOPICS[0], T0, src.raw_color(0), "rgb8")
    w.image(TUM_TOPICS[1], T0, src.raw_depth(0).numpy()[::2, ::2], "32FC1")
    w.close()
    out["half_depth"] = root / "half_depth.bag"
    w = BagWriter(root / "yuv.bag")
    w.camera_info(TUM_TOPICS[2], T0, src.raw_intrinsics)
    w.image(TUM_TOPICS[0], T0, src.raw_color(0)[..., :2], "yuv422")
    w.image(TUM_TOPICS[1], T0, src.raw_depth(0).numpy(), "32FC1")
    w.close()
    out["yuv"] = root / "yuv.bag"
    BagWriter(root / "empty.bag").close()
    data = out["ros1"].read_bytes()
    (root / "truncated.bag").write_bytes(data[: len(data) // 2])
    out["truncated"] = root / "truncated.bag"
    out["empty"] = root / "empty.bag"
    return out


def _same_frames(ds, src, frames=range(N), atol=0.0):
    for i in frames:
        a, b = ds[i], src[i]
        if atol:
            assert (a.color - b.color).abs().mean() < atol
        else:
            assert torch.equal(a.color, b.color), i
        assert torch.equal(a.depth, b.depth), i


def test_ros1_bag_with_tum_topics_gives_the_source_frames_camera_stamps_and_ground_truth(bags):
    src = bags["src"]
    assert detect_layout(bags["ros1"]) == "bag"
    ds = load_dataset(bags["ros1"], groundtruth=str(bags["gt"]), relative_to_first=False, undistort=False)
    assert isinstance(ds, BagDataset) and ds.name == "tum" and len(ds) == N
    assert (ds.color_topic, ds.depth_topic, ds.camera_info_topic) == TUM_TOPICS
    assert ds.depth_encoding == "32FC1" and ds.depth_scale == 1.0
    assert ds.raw_intrinsics == src.raw_intrinsics and ds.intrinsics == src.intrinsics
    _same_frames(ds, src)  # rgb8 and float32 metres: bit for bit
    # stamps: the colour frames', to the nanosecond as Python's int / int rounds them
    assert ds.timestamps == [(T0 + i * DT) / 10**9 for i in range(N)]
    np.testing.assert_allclose(ds.gt_poses.numpy(), src.gt_poses[:N].numpy(), atol=1e-6)
    assert ds.gt_file == bags["gt"] and bool(ds.valid_poses.all())
    # the defaults: poses relative to the first frame (as TUM's loader) and the CameraInfo's distortion undone
    ds = BagDataset(bags["ros1"], groundtruth=bags["gt"])
    assert torch.allclose(ds.gt_poses[0], torch.eye(4), atol=1e-6)
    assert ds.distortion == DISTORTION
    # without ground truth: unknown poses, every paired frame kept
    ds = BagDataset(bags["ros1"], stride=2, max_frames=3)
    assert len(ds) == 3 and not bool(ds.valid_poses.any())
    assert ds.timestamps == [(T0 + i * DT) / 10**9 for i in (0, 2, 4)]
    assert torch.equal(ds[2].depth, src[4].depth)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bag_with_realsense_topics_and_millimetre_depth(bags, storage):
    src = bags["src"]
    assert detect_layout(bags[storage]) == "bag"
    ds = BagDataset(bags[storage], undistort=False)
    assert (ds.color_topic, ds.depth_topic, ds.camera_info_topic) == RS_TOPICS
    assert ds.depth_encoding == "16UC1" and ds.depth_scale == 1000.0 and len(ds) == N
    assert ds.raw_intrinsics == src.raw_intrinsics
    for i in range(N):
        f = ds[i]
        assert torch.equal(f.color, src[i].color)  # rgb8 (sqlite3) and bgr8 (mcap) both give the RGB
        mm = np.round(src.raw_depth(i).numpy() * 1000).astype(np.uint16)
        assert torch.equal(f.depth, torch.from_numpy(mm.astype(np.float32)) / 1000.0)
        assert float((f.depth - src[i].depth).abs().max()) <= 0.0005 + 1e-6
    # depth_scale: the 16-bit value per metre
    assert torch.equal(BagDataset(bags[storage], depth_scale=500, undistort=False)[1].depth, 2 * ds[1].depth)


def test_compressed_and_other_colour_encodings(bags):
    src = bags["src"]
    png = BagDataset(bags["png"], undistort=False)
    assert len(png) == 3
    _same_frames(png, src, range(3))  # lossless
    jpeg = BagDataset(bags["jpeg"], undistort=False)
    assert jpeg.color_topic == RS_TOPICS[0] + "/compressed"
    _same_frames(jpeg, src, range(3), atol=0.03)  # lossy colour, the same depth frames
    rgba = BagDataset(bags["rgba"], undistort=False)
    assert np.array_equal(rgba.raw_color(1), src.raw_color(1))
    mono = BagDataset(bags["mono"], undistort=False).raw_color(1)
    assert np.array_equal(mono, np.repeat(src.raw_color(1)[..., :1], 3, axis=2))


def test_pairing_drops_a_colour_frame_without_depth_within_max_dt(bags):
    ds = BagDataset(bags["gap"], undistort=False, max_dt=0.02)
    assert ds.timestamps == [(T0 + i * DT) / 10**9 for i in (0, 1, 3, 4)]
    src = bags["src"]
    assert torch.equal(ds[2].color, src[3].color) and torch.equal(ds[2].depth, src[3].depth)
    # the TUM loader's 0.08 s pairs frame 2 with the nearest depth (frame 1's, 26 ms before; frame 3's is 40 ms after)
    wide = BagDataset(bags["gap"], undistort=False)
    assert len(wide) == 5 and torch.equal(wide[2].depth, src[1].depth)
    # ground truth only where the trajectory is: frames past its end are dropped
    short = write_groundtruth(bags["root"] / "gt3.txt", src, frames=3)
    assert len(BagDataset(bags["gap"], groundtruth=short, max_dt=0.01)) == 2


def test_topic_overrides_and_the_errors_that_name_the_topics(bags):
    with pytest.raises(SlamInputError, match=r"several colour topics \(/camera/rgb/image_color, "
                                             r"/camera/rgb/image_rect_color\); name one with data.options.color_topic"):
        BagDataset(bags["two_colour"])
    ds = BagDataset(bags["two_colour"], color_topic="/camera/rgb/image_rect_color", undistort=False)
    assert np.array_equal(ds.raw_color(0), bags["src"].raw_color(2))
    with pytest.raises(SlamInputError, match=r"data.options.depth_topic = '/camera/nope' is not a topic of the bag; "
                                             r"its sensor_msgs/msg/Image topics: /camera/depth/image \("):
        BagDataset(bags["ros1"], depth_topic="/camera/nope")
    with pytest.raises(SlamInputError, match=r"camera_info_topic = '/camera/depth/image' is a sensor_msgs/msg/Image "
                                             r"topic, expected sensor_msgs/msg/CameraInfo"):
        BagDataset(bags["ros1"], camera_info_topic="/camera/depth/image")
    # the colour images as depth: an option may name any Image topic, its encoding is checked
    with pytest.raises(SlamInputError, match=r"depth encoding 'rgb8' is not read \(expected one of 16UC1"):
        BagDataset(bags["ros1"], depth_topic="/camera/rgb/image_color")


@pytest.mark.parametrize("name, message", [
    ("no_depth", r"no_depth.bag: no depth \(sensor_msgs/Image with 'depth' in its name\) topic; the bag has: "
                 r"/camera/ir/image \(sensor_msgs/msg/Image, 2 messages\), /camera/rgb/camera_info \("
                 r"sensor_msgs/msg/CameraInfo, 1 messages\), /camera/rgb/image_color \(sensor_msgs/msg/Image, 2 "
                 r"messages\) \(name one with data.options.depth_topic\)"),
    ("half_depth", r"half_depth.bag: colour /camera/rgb/image_color is 60x80 but depth /camera/depth/image is 30x40: "
                   r"depth must be registered to the colour camera"),
    ("yuv", r"yuv.bag: topic /camera/rgb/image_color: colour encoding 'yuv422' is not read"),
    ("truncated", r"truncated.bag: cannot open the ROS 1 bag, truncated or corrupt\?"),
    ("empty", r"empty.bag: the ROS 1 bag holds no messages"),
])
def test_bad_bags_give_one_line_naming_the_file_and_topic(bags, name, message):
    with pytest.raises(SlamInputError, match=message) as err:
        BagDataset(bags[name])
    assert "\n" not in str(err.value)


def test_image_rows_padding_and_byte_order_are_honoured():
    from types import SimpleNamespace

    from slam.data.bag_messages import DEPTH_ENCODINGS, decode_image

    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000 + 7
    padded = np.zeros((3, 12), dtype=np.uint8)  # rows of 8 bytes of pixels, 4 of padding
    padded[:, :8] = depth.astype(">u2").view(np.uint8).reshape(3, 8)
    msg = SimpleNamespace(encoding="16UC1", is_bigendian=1, height=3, width=4, step=12, data=padded.reshape(-1))
    out = decode_image(msg, "x.bag: topic /d", DEPTH_ENCODINGS)
    assert out.dtype == np.uint16 and np.array_equal(out[..., 0], depth)
    short = SimpleNamespace(encoding="32FC1", is_bigendian=0, height=3, width=4, step=16, data=np.zeros(40, np.uint8))
    with pytest.raises(SlamInputError, match=r"x.bag: topic /d: a 3x4 32FC1 image holds 40 bytes with rows of 16"):
        decode_image(short, "x.bag: topic /d", DEPTH_ENCODINGS)


def test_any_preset_reads_a_bag_with_the_bag_loaders_options(bags, capsys):
    from slam.cli import main

    assert main(["run", "--config", "tum", "--data", str(bags["ros1"]), "--out", str(bags["root"] / "never"),
                 "data.options.camera=fr1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config key 'data.options.camera' is not an option of bag data" in err[0]
    with pytest.raises(SlamInputError, match=r"groundtruth.txt: not a folder \(nor a ROS 1 bag, a .bag file\)"):
        detect_layout(bags["gt"])


def test_camera_options_override_the_camera_info(bags):
    src = bags["src"]
    ds = BagDataset(bags["ros1"], intrinsics={"fx": 50.0, "fy": 51.0, "cx": 40.0, "cy": 30.0}, distortion=[])
    k = ds.raw_intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.height, k.width) == (50.0, 51.0, 40.0, 30.0, 60, 80) and ds.distortion is None
    with pytest.raises(SlamInputError, match=r"depth_scale is for 16-bit depth; /camera/depth/image is 32FC1"):
        BagDataset(bags["ros1"], depth_scale=1000)
    # a model the undistortion does not apply is refused unless undistortion is off
    w = BagWriter(bags["root"] / "fisheye.bag")
    w.camera_info(TUM_TOPICS[2], T0, src.raw_intrinsics, (0.1, 0.01, 0.0, 0.0), model="equidistant")
    w.image(TUM_TOPICS[0], T0, src.raw_color(0), "rgb8")
    w.image(TUM_TOPICS[1], T0, src.raw_depth(0).numpy(), "32FC1")
    w.close()
    with pytest.raises(SlamInputError, match=r"distortion model 'equidistant' .* is not undone here"):
        BagDataset(bags["root"] / "fisheye.bag")
    assert BagDataset(bags["root"] / "fisheye.bag", undistort=False).distortion is None


def test_without_the_bags_extra_opening_a_bag_names_the_install_command(bags, monkeypatch):
    from slam.data import bag

    monkeypatch.setitem(sys.modules, "rosbags.rosbag1", None)  # import fails as if not installed
    assert detect_layout(bags["ros1"]) == "bag"  # recognised without it
    with pytest.raises(SlamInputError, match=r"reading ROS bags needs rosbags, which is not installed; install the "
                                             r"bags extra: python3 -m pip install -e \".*\[bags\]\" \(or: python3 -m "
                                             r"pip install \"rosbags>=0.11\"\)") as err:
        bag.BagDataset(bags["ros1"])
    assert "\n" not in str(err.value)


def write_tum_folder_bag(ds, path, frames=None):
    """A TUM folder (``ds``, a TUMDataset) as a ROS 1 bag in TUM's own layout: its colour and depth frames at the
    stamps their file names give, depth in 32FC1 metres as the folder loads them; returns the bag."""
    n = len(ds) if frames is None else frames
    stamps = [(stamp_ns(ds.color_paths[i].stem), stamp_ns(ds.depth_paths[i].stem)) for i in range(n)]
    return write_rgbd_bag(path, ds, frames=n, distortion=None, stamps=stamps)


@pytest.mark.slow
def test_lrslam_run_on_a_bag_gives_the_trajectory_of_the_folder_it_was_made_from(bags, tmp_path, capsys):
    """The tiny sequence as a TUM folder, and that folder as a ROS 1 bag with TUM's topics and its ground truth file:
    the same frames bit for bit, camera, stamps and first pose, so the same trajectory.txt with the tum preset.
    (Through a TUM folder: the Replica folder's poses are matrices that TUM rows, quaternions, carry only to a
    float32 ulp, and the first pose starts the trajectory.)"""
    from slam.cli import main
    from slam.data import TUMDataset, TUMWriter

    from tests.slam.conftest import TINY

    src = bags["src"]
    folder = tmp_path / "tiny_tum"
    with TUMWriter(folder, src.raw_intrinsics, depth_scale=1000.0) as rec:
        for i in range(6):
            f = src[i]
            rec.add(f.timestamp, src.raw_color(i), f.depth.numpy(), depth_timestamp=f.timestamp + 0.005,
                    pose=f.pose.double().numpy())
    tum = TUMDataset(folder)
    bag = write_tum_folder_bag(tum, tmp_path / "tiny_tum.bag")
    from_bag = BagDataset(bag, groundtruth=folder / "groundtruth.txt")
    assert from_bag.timestamps == tum.timestamps and torch.equal(from_bag.gt_poses, tum.gt_poses)
    _same_frames(from_bag, tum, range(6))
    runs = {}
    for name, data in (("folder", folder), ("bag", bag)):
        out = tmp_path / name
        rc = main(["run", "--config", "tum", "--data", str(data), "--out", str(out), "--quiet", "--no-mesh", *TINY,
                   "data.options.crop_size=null", "data.options.crop_edge=0", "tracking.ignore_edge=[4,4]",
                   *([f"data.options.groundtruth={folder / 'groundtruth.txt'}"] if name == "bag" else [])])
        assert rc == 0, capsys.readouterr().err
        runs[name] = hashlib.sha256((out / "trajectory.txt").read_bytes()).hexdigest()
    assert runs["bag"] == runs["folder"]


def test_a_resume_fingerprint_sees_a_bag_replaced_by_another(bags, tmp_path):
    """A bag has no image file per frame: the resume check sizes up its files instead (a ROS 1 file, the ROS 2
    folder's storage files), so another recording under the same name is refused."""
    import shutil

    from slam.data.bag import BagDataset
    from slam.engine.setup import data_fingerprint, fingerprint_mismatch

    bag = tmp_path / "run.bag"
    shutil.copy(bags["ros1"], bag)
    indices = list(range(N))
    stored = data_fingerprint(BagDataset(bag), indices)
    assert fingerprint_mismatch(stored, BagDataset(bag), indices) is None
    assert BagDataset(bags["sqlite3"]).source_files and all(p.suffix == ".db3"
                                                            for p in BagDataset(bags["sqlite3"]).source_files)
    bag.unlink()
    write_rgbd_bag(bag, bags["src"], color="png")  # the same frames and stamps, recorded otherwise
    assert "sizes" in fingerprint_mismatch(stored, BagDataset(bag), indices)
