"""TUM RGB-D benchmark sequences (native layout).

::

    <seq>/rgb.txt, depth.txt        "timestamp file" per line, '#' comments
    <seq>/groundtruth.txt           "timestamp tx ty tz qx qy qz qw" camera-to-world (OpenCV camera axes)
    <seq>/associations.txt          optional "rgb_ts rgb_file depth_ts depth_file" (TUM associate.py output)
    <seq>/rgb/*.png, depth/*.png    8-bit RGB; 16-bit depth, metres = value / 5000, 0 = no measurement
    <seq>/calibration.yaml          optional: the camera of a recording made with another sensor
                                    (slam.data.calibration; what slam.data.tum_writer writes)

The text files are read by :mod:`slam.data.tum_format` (the one reader of TUM rows, slam.eval's too).

Association (reference loaders): every rgb frame takes the nearest depth frame and the ground truth at its
timestamp, and is kept only if both are within ``max_dt`` (0.08 s); then frames closer than ``min_dt``
(1/32 s) to the previous kept one are dropped. If ``associations.txt`` exists its rgb/depth pairs are used
instead. Ground truth is interpolated at the rgb timestamp (linear position, slerp rotation) when it has
samples on both sides within ``max_dt``, else the nearest sample is used. By default poses are expressed
relative to the first kept frame (frame 0 = identity), as the reference configs' scene bounds assume.

Depth is registered to the colour camera by the Kinect driver, so one camera model serves both; colour is
undistorted with the sequence's Brown-Conrady coefficients (depth is not), as the reference does.

The camera, in order of precedence: explicit options (``intrinsics``, ``distortion``, ``depth_scale``, or a
named ``camera``) > the folder's ``calibration.yaml`` > the freiburg1/2/3 calibration guessed from the folder
name (else the ROS default). A folder without ``groundtruth.txt`` (a recording of one's own) loads with
unknown (all-NaN) poses: SLAM runs, ATE is not computed.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from slam.data.association import nearest, poses_at, spaced
from slam.data.base import RGBDDataset
from slam.data.calibration import (
    CALIBRATION_FILE, parse_depth_scale, parse_distortion, parse_intrinsics, read_calibration,
)
from slam.data.tum_format import ASSOCIATION_FILES, read_associations, read_tum_list, read_tum_poses
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["TUMDataset", "TUM_CAMERAS", "TUM_DEPTH_SCALE", "looks_like", "read_tum_list"]

log = logging.getLogger(__name__)

TUM_DEPTH_SCALE = 5000.0

#: per-sensor calibration on the raw 640x480 images: (intrinsics, distortion k1 k2 p1 p2 k3)
TUM_CAMERAS: dict[str, tuple[Intrinsics, tuple[float, ...] | None]] = {
    "fr1": (Intrinsics(517.3, 516.5, 318.6, 255.3, 480, 640), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": (Intrinsics(520.9, 521.0, 325.1, 249.7, 480, 640), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": (Intrinsics(535.4, 539.2, 320.1, 247.6, 480, 640), None),
    # ROS default for unrectified use when the sensor is unknown
    "default": (Intrinsics(525.0, 525.0, 319.5, 239.5, 480, 640), None),
}


def looks_like(root: Path) -> bool:
    """Whether ``root`` holds a TUM sequence: an ``rgb.txt`` list or an associations file."""
    return (root / "rgb.txt").exists() or any((root / n).exists() for n in ASSOCIATION_FILES)


def _pairs(root: Path, association: str, max_dt: float):
    """The colour frames and their depth frames: ``(rgb timestamps [N], rgb files, depth files, the file the
    pairs come from, the number of rgb entries before pairing, whether an associations file gave them)``."""
    assoc_file = next((root / n for n in ASSOCIATION_FILES if (root / n).exists()), None)
    if association not in ("auto", "file", "timestamps"):
        raise SlamInputError(f"association must be auto, file or timestamps, got {association!r}")
    if association == "file" and assoc_file is None:
        raise SlamInputError(f"{root}: association='file' but there is no associations.txt")
    if assoc_file is not None and association != "timestamps":
        rgb_ts, rgb_files, depth_files = read_associations(assoc_file)
        return rgb_ts, rgb_files, depth_files, assoc_file, len(rgb_ts), True
    rgb_ts, rgb_files = read_tum_list(root / "rgb.txt")
    depth_ts, dfiles = read_tum_list(root / "depth.txt")
    if len(rgb_ts) == 0 or len(depth_ts) == 0:
        raise SlamInputError(f"{root}: rgb.txt has {len(rgb_ts)} and depth.txt {len(depth_ts)} entries")
    order = np.argsort(depth_ts, kind="stable")
    dts = depth_ts[order]
    nd = order[nearest(dts, rgb_ts)] if len(dts) > 1 else np.zeros(len(rgb_ts), dtype=np.int64)
    keep = np.abs(depth_ts[nd] - rgb_ts) < max_dt
    rgb_files = [f for f, k in zip(rgb_files, keep) if k]
    depth_files = [dfiles[j] for j, k in zip(nd, keep) if k]
    return rgb_ts[keep], rgb_files, depth_files, root / "depth.txt", len(rgb_ts), False


def _ground_truth(root: Path, rgb_ts: np.ndarray, max_dt: float, interpolate: bool):
    """``(ground-truth file or None, its timestamps, poses [N, 4, 4] at rgb_ts, [N] mask of frames with ground
    truth)``; without a ground-truth file every pose is NaN and every frame counts as having one."""
    gt_path = next((root / n for n in ("groundtruth.txt", "pose.txt") if (root / n).exists()), None)
    if gt_path is None:
        # a recording of one's own: SLAM needs no ground truth, only the evaluation does
        log.warning("%s: no groundtruth.txt (or pose.txt): poses unknown, ATE will not be computed", root)
        return None, np.zeros(0), np.full((len(rgb_ts), 4, 4), np.nan), np.ones(len(rgb_ts), dtype=bool)
    data = read_tum_poses(gt_path, what="ground-truth row")
    data = data[np.argsort(data[:, 0], kind="stable")]
    poses, has_gt = poses_at(data[:, 0], data[:, 1:8], rgb_ts, max_dt, interpolate)
    if not has_gt.all():
        log.info("%s: %d of %d frames have no ground truth within %.3f s and are dropped",
                 root, int((~has_gt).sum()), len(has_gt), max_dt)
    return gt_path, data[:, 0], poses, has_gt


def _image_size(path: Path) -> tuple[int, int]:
    """``(height, width)`` of an image from its header; SlamInputError naming it if unreadable."""
    import imageio.v3 as iio

    if not path.is_file():
        raise SlamInputError(f"{path}: image file not found")
    try:
        shape = iio.improps(path, plugin="pillow").shape
    except Exception as exc:  # imageio raises many types for corrupt files
        raise SlamInputError(f"{path}: cannot read depth image ({type(exc).__name__}: {exc})") from None
    return int(shape[0]), int(shape[1])


def _camera_for(root: Path) -> str:
    name = root.resolve().name.lower()
    for key, pat in (("fr1", r"(freiburg1|fr1)"), ("fr2", r"(freiburg2|fr2)"), ("fr3", r"(freiburg3|fr3)")):
        if re.search(pat, name):
            return key
    return "default"


class TUMDataset(RGBDDataset):
    """A TUM RGB-D sequence (see module docstring).

    Args:
        path: the sequence folder.
        camera: ``"auto"`` (the folder's ``calibration.yaml`` if any, else from the folder name: freiburg1/fr1,
            fr2, fr3, else the ROS default), or a key of :data:`TUM_CAMERAS`.
        intrinsics: explicit camera on the raw images, overriding ``camera`` and the calibration file: an
            :class:`Intrinsics` or a mapping ``{fx, fy, cx, cy[, width, height]}`` (pixels; the size defaults to
            the depth images').
        distortion: ``(k1, k2, p1, p2[, k3])``; default: the chosen camera's (none for ``intrinsics``).
        calibration: a calibration file (relative to the folder) instead of ``<folder>/calibration.yaml``.
        association: ``"auto"`` (``associations.txt`` if present, else timestamps), ``"file"`` or
            ``"timestamps"``.
        max_dt: seconds; largest rgb-depth and rgb-ground-truth gap accepted (reference 0.08).
        min_dt: seconds; drop frames closer than this to the previous kept one (reference 1/32; timestamp
            association only).
        interpolate_gt: interpolate ground truth at the rgb timestamp (else nearest sample).
        relative_to_first: express poses relative to the first kept frame (reference behaviour).
        depth_scale: raw / metres; default the calibration file's, else 5000 (TUM's Kinect).
        **options: crop_size, crop_edge, undistort, stride, max_frames (see :class:`RGBDDataset`).

    Attributes: ``camera`` (``fr1``/``fr2``/``fr3``/``default``, ``custom`` for the ``intrinsics`` option, ``file``
    for a calibration file), ``calibration_file`` (Path or None), ``gt_file`` (Path or None).
    """

    def __init__(
        self,
        path,
        *,
        camera: str = "auto",
        intrinsics: Intrinsics | dict | None = None,
        distortion=None,
        calibration: str | Path | None = None,
        association: str = "auto",
        max_dt: float = 0.08,
        min_dt: float = 1.0 / 32.0,
        interpolate_gt: bool = True,
        relative_to_first: bool = True,
        depth_scale: float | None = None,
        **options,
    ) -> None:
        root = Path(path)
        if not root.is_dir():
            raise SlamInputError(f"{root}: TUM sequence folder not found")
        self.name = root.name
        rgb_ts, rgb_files, depth_files, source, n_rgb, use_file = _pairs(root, association, max_dt)
        gt_path, gt_ts, poses, keep = _ground_truth(root, rgb_ts, max_dt, interpolate_gt)
        if not use_file and min_dt > 0:
            keep = spaced(rgb_ts, keep, min_dt)
        if not keep.any():
            # a recording without groundtruth.txt gets here when no colour frame has a depth frame within max_dt
            gt_span = f"ground truth {gt_ts[0]:.3f}..{gt_ts[-1]:.3f}" if len(gt_ts) else "no ground truth"
            what = "depth and ground truth" if gt_path is not None else "a depth frame"
            raise SlamInputError(
                f"{source}: empty association: no rgb frame has {what} within {max_dt} s "
                f"(rgb {n_rgb} frames, {gt_span})"
            )
        idx = np.flatnonzero(keep)
        poses = poses[idx]
        if relative_to_first and gt_path is not None:
            poses = np.linalg.inv(poses[0]) @ poses
        self.gt_file = gt_path

        depth_paths = [root / depth_files[k] for k in idx]
        intrinsics, distortion, depth_scale = self._camera(root, depth_paths[0], camera, intrinsics, distortion,
                                                           calibration, depth_scale)

        self._setup(
            root=root,
            color_paths=[root / rgb_files[k] for k in idx],
            depth_paths=depth_paths,
            poses=poses,
            timestamps=rgb_ts[idx],
            intrinsics=intrinsics,
            depth_scale=depth_scale,
            distortion=distortion,
            allow_invalid_poses=gt_path is None,
            pose_source=gt_path,
            **options,
        )

    def _camera(self, root: Path, depth0: Path, camera, intrinsics, distortion, calibration, depth_scale):
        """(intrinsics, distortion, depth scale): explicit options > calibration file > folder-name guess."""
        calib_path = root / (calibration if calibration is not None else CALIBRATION_FILE)
        calib = read_calibration(calib_path) if calibration is not None or calib_path.is_file() else None
        self.calibration_file = None
        size = _image_size(depth0)
        if intrinsics is not None:
            intr = parse_intrinsics(intrinsics, f"{root}: option 'intrinsics'", image_size=size)
            cam_dist, self.camera, where = None, "custom", "option 'intrinsics'"
        elif camera != "auto" or calib is None:
            key = _camera_for(root) if camera == "auto" else camera
            if key not in TUM_CAMERAS:
                raise SlamInputError(f"unknown TUM camera {camera!r}; expected auto or one of {list(TUM_CAMERAS)}")
            intr, cam_dist = TUM_CAMERAS[key]
            self.camera, where = key, f"the {key} calibration; another camera needs {root / CALIBRATION_FILE}"
            if key == "default" and size == (intr.height, intr.width):
                log.warning("%s: sensor not recognised from the folder name and no %s; using the ROS default camera",
                            root, CALIBRATION_FILE)
        else:
            intr, cam_dist = calib.intrinsics, calib.distortion
            self.camera, where, self.calibration_file = "file", f"{calib.path}, keys height and width", calib.path
        if size != (intr.height, intr.width):
            raise SlamInputError(f"{depth0}: depth image is {size[0]}x{size[1]}, expected {intr.height}x{intr.width} "
                                 f"(the image size in {where})")
        dist = cam_dist if distortion is None else parse_distortion(distortion, f"{root}: option 'distortion'")
        if depth_scale is not None:
            scale = parse_depth_scale(depth_scale, f"{root}: option 'depth_scale'")
        elif calib is not None and calib.depth_scale is not None:
            scale = calib.depth_scale
        else:
            scale = TUM_DEPTH_SCALE
        return intr, dist, scale
