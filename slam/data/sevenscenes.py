"""Microsoft 7-Scenes sequences (Shotton et al., CVPR 2013), one sequence folder such as ``chess/seq-01``.

::

    <seq>/frame-000000.color.png    640x480 8-bit RGB (some copies carry frame-000000.color.jpg)
    <seq>/frame-000000.depth.png    640x480 uint16 millimetres, 65535 = no measurement
    <seq>/frame-000000.pose.txt     4x4 camera-to-world, 4 lines of 4 numbers (KinectFusion's tracking)

Kinect v1 at 30 Hz: timestamps are ``frame number / 30`` s. The depth camera's intrinsics, fx = fy = 585,
cx = 320, cy = 240, serve colour as well. The depth images are **not registered** to the colour images (the
two Kinect cameras sit about 2.5 cm apart and the dataset ships no calibration between them), so a colour
pixel and the depth pixel at the same ``(u, v)`` see points a few pixels apart, most at depth edges and near
the camera: colour supervision is slightly offset and blurred, geometry and poses are not affected. This is
the common practice for 7-Scenes. Poses are used as stored (camera-to-world, OpenCV axes); no GT mesh.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from slam.data.base import RGBDDataset
from slam.data.calibration import parse_depth_scale, parse_intrinsics
from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["SevenScenesDataset", "SEVEN_SCENES_INTRINSICS", "SEVEN_SCENES_DEPTH_SCALE", "SEVEN_SCENES_INVALID",
           "looks_like", "scene_folder_hint"]

#: the Kinect depth camera as the dataset page gives it, on the raw 640x480 images
SEVEN_SCENES_INTRINSICS = Intrinsics(585.0, 585.0, 320.0, 240.0, 480, 640)
SEVEN_SCENES_DEPTH_SCALE = 1000.0  # millimetres
SEVEN_SCENES_INVALID = 65535

_FRAME = re.compile(r"frame-(\d+)\.(color\.png|color\.jpg|depth\.png|pose\.txt)$")


def looks_like(root: Path) -> bool:
    """Whether ``root`` is a 7-Scenes sequence folder (``frame-NNNNNN.pose.txt`` or ``.color.*`` files)."""
    return any(root.glob("frame-*.pose.txt")) or any(root.glob("frame-*.color.*"))


def scene_folder_hint(root: Path) -> str | None:
    """For a 7-Scenes scene folder (several ``seq-NN`` sequences, none at the top): what to pass instead."""
    sequences = sorted(p for p in root.glob("seq-*") if p.is_dir() and looks_like(p))
    if not sequences:
        return None
    return f"{root}: a 7-Scenes scene with {len(sequences)} sequences; pass one sequence folder, e.g. {sequences[0]}"


def _image_size(path: Path) -> tuple[int, int]:
    import imageio.v3 as iio

    try:
        shape = iio.improps(path, plugin="pillow").shape
    except FileNotFoundError:
        raise SlamInputError(f"{path}: image file not found") from None
    except Exception as exc:  # imageio raises many types for corrupt files
        raise SlamInputError(f"{path}: cannot read image ({type(exc).__name__}: {exc})") from None
    return int(shape[0]), int(shape[1])


def read_pose(path: Path) -> np.ndarray:
    """A 7-Scenes pose file as a ``[4, 4]`` float64 camera-to-world matrix; SlamInputError naming it if bad."""
    try:
        rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    except FileNotFoundError:
        raise SlamInputError(f"{path}: pose file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SlamInputError(f"{path}: cannot read ({exc})") from None
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        shape = f"{len(rows)} lines of {sorted({len(r) for r in rows})} numbers" if rows else "an empty file"
        raise SlamInputError(f"{path}: expected a 4x4 matrix (4 lines of 4 numbers), got {shape}")
    try:
        m = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
    except ValueError as exc:
        raise SlamInputError(f"{path}: non-numeric value in the pose ({exc})") from None
    if not np.isfinite(m).all():
        raise SlamInputError(f"{path}: pose contains NaN or inf")
    r = m[:3, :3]
    ortho = float(np.abs(r.T @ r - np.eye(3)).max())
    det = float(np.linalg.det(r))
    last = float(np.abs(m[3] - [0.0, 0.0, 0.0, 1.0]).max())
    if ortho > 1e-3 or abs(det - 1.0) > 1e-3 or last > 1e-3:
        raise SlamInputError(f"{path}: not a rigid camera-to-world transform (|R^T R - I| = {ortho:.3g}, "
                             f"det R = {det:.4f}, last row {m[3].tolist()})")
    return m


class SevenScenesDataset(RGBDDataset):
    """A 7-Scenes sequence folder (see module docstring).

    Args:
        path: the sequence folder (``<scene>/seq-NN``) holding ``frame-NNNNNN.{color.png,depth.png,pose.txt}``.
        intrinsics: override the Kinect depth camera: an :class:`Intrinsics` or a mapping
            ``{fx, fy, cx, cy[, width, height]}`` on the raw images (the size defaults to 480x640).
        depth_scale: raw / metres (1000: millimetres).
        **options: crop_size, crop_edge, stride, max_frames (see :class:`RGBDDataset`); there is no distortion.
    """

    def __init__(self, path, *, intrinsics: Intrinsics | dict | None = None,
                 depth_scale: float = SEVEN_SCENES_DEPTH_SCALE, **options) -> None:
        root = Path(path)
        if not root.is_dir():
            raise SlamInputError(f"{root}: 7-Scenes sequence folder not found")
        self.name = f"{root.parent.name}/{root.name}" if root.parent.name else root.name
        files: dict[str, dict[int, Path]] = {"color": {}, "depth": {}, "pose": {}}
        for p in root.iterdir():
            m = _FRAME.match(p.name)
            if m:
                kind = m.group(2).split(".")[0]
                i = int(m.group(1))
                if kind == "color" and i in files["color"]:
                    raise SlamInputError(f"{root}: frame {i} has both {files['color'][i].name} and {p.name}")
                files[kind][i] = p
        ids = sorted(files["color"])
        if not ids:
            raise SlamInputError(f"{root}: no frame-NNNNNN.color.png (or .jpg) images: not a 7-Scenes sequence")
        for kind, suffix in (("depth", "depth.png"), ("pose", "pose.txt")):
            missing = sorted(set(ids) - set(files[kind]))
            if missing:
                raise SlamInputError(f"{root / f'frame-{missing[0]:06d}.{suffix}'}: {kind} file not found "
                                     f"({len(missing)} of {len(ids)} colour frames have no {kind} file)")
        extra = sorted(set(files["depth"]) - set(ids))
        if extra:
            raise SlamInputError(f"{root / f'frame-{extra[0]:06d}.color.png'}: colour image not found "
                                 f"(frame {extra[0]} has a depth image)")
        poses = np.stack([read_pose(files["pose"][i]) for i in ids])
        if intrinsics is None:
            intrinsics = SEVEN_SCENES_INTRINSICS
        else:
            intrinsics = parse_intrinsics(intrinsics, f"{root}: option 'intrinsics'",
                                          image_size=(SEVEN_SCENES_INTRINSICS.height, SEVEN_SCENES_INTRINSICS.width))
        depth_scale = parse_depth_scale(depth_scale, f"{root}: option 'depth_scale'")
        first = files["depth"][ids[0]]
        size = _image_size(first)
        if size != (intrinsics.height, intrinsics.width):
            raise SlamInputError(f"{first}: depth image is {size[0]}x{size[1]}, expected "
                                 f"{intrinsics.height}x{intrinsics.width} (7-Scenes: 480x640)")
        self._setup(
            root=root,
            color_paths=[files["color"][i] for i in ids],
            depth_paths=[files["depth"][i] for i in ids],
            poses=poses,
            timestamps=[i / 30.0 for i in ids],
            intrinsics=intrinsics,
            depth_scale=depth_scale,
            **options,
        )

    def load_color(self, i: int) -> torch.Tensor:
        # the base class resizes colour to the depth size (for ScanNet's 1296x968); here colour and depth are
        # both 640x480, so another size is a damaged file, not something to resize silently
        path = self._color_paths[i]
        size = _image_size(path)
        if size != (self.raw_intrinsics.height, self.raw_intrinsics.width):
            raise SlamInputError(f"{path}: colour image is {size[0]}x{size[1]}, expected "
                                 f"{self.raw_intrinsics.height}x{self.raw_intrinsics.width} (the depth images' size)")
        return super().load_color(i)

    def load_depth(self, i: int) -> torch.Tensor:
        """Depth of frame ``i``: ``[H, W]`` float32 metres, 0 = invalid (the raw 65535 marker included)."""
        depth = super().load_depth(i)
        # nearest resizing and cropping keep values exact, so the marker is still recognisable here
        marker = torch.tensor(float(SEVEN_SCENES_INVALID), dtype=torch.float32) / self.depth_scale
        return torch.where(depth == marker, torch.zeros_like(depth), depth)
