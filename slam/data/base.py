"""Shared machinery of the RGB-D loaders: image reading with checks, undistortion, resize and crop."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from slam.core.camera import pixel_directions
from slam.data.resize import resize_and_crop
from slam.data.types import Frame, Intrinsics
from slam.errors import SlamInputError
from slam.core.geometry import check_rigid

__all__ = ["RGBDDataset", "read_color", "read_depth", "undistort_grid"]

log = logging.getLogger(__name__)


def read_color(path: Path) -> np.ndarray:
    """Read an 8-bit colour image as ``[H, W, 3]`` uint8 RGB (alpha dropped); SlamInputError if unreadable."""
    import imageio.v3 as iio

    try:
        img = iio.imread(path, plugin="pillow")  # one decoder: no slow fall-through for corrupt files
    except FileNotFoundError:
        raise SlamInputError(f"{path}: colour image not found") from None
    except Exception as exc:  # imageio raises many types for corrupt files
        raise SlamInputError(f"{path}: cannot read colour image ({type(exc).__name__}: {exc})") from None
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise SlamInputError(f"{path}: expected an RGB colour image, got array of shape {img.shape}")
    if img.dtype != np.uint8:
        raise SlamInputError(f"{path}: expected 8-bit colour, got dtype {img.dtype}")
    return img[..., :3]


def read_depth(path: Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a 16-bit depth PNG as ``[H, W]`` uint16; SlamInputError if unreadable, not uint16 or not ``shape``."""
    import imageio.v3 as iio

    try:
        img = iio.imread(path, plugin="pillow")  # one decoder: no slow fall-through for corrupt files
    except FileNotFoundError:
        raise SlamInputError(f"{path}: depth image not found") from None
    except Exception as exc:
        raise SlamInputError(f"{path}: cannot read depth image ({type(exc).__name__}: {exc})") from None
    if img.ndim != 2:
        raise SlamInputError(f"{path}: expected a single-channel depth image, got array of shape {img.shape}")
    if img.dtype != np.uint16:
        raise SlamInputError(f"{path}: expected a 16-bit depth PNG (uint16), got dtype {img.dtype}")
    if shape is not None and tuple(img.shape) != tuple(shape):
        raise SlamInputError(
            f"{path}: depth image is {img.shape[0]}x{img.shape[1]}, expected {shape[0]}x{shape[1]} "
            "(all depth images of a sequence must match the camera size)"
        )
    return img


def undistort_grid(intr: Intrinsics, dist: Sequence[float]) -> torch.Tensor:
    """Sampling grid ``[1, H, W, 2]`` (grid_sample, align_corners=True) that undistorts an image.

    Brown-Conrady model with OpenCV's coefficient order ``(k1, k2, p1, p2[, k3])``; the output camera keeps
    the same K (as ``cv2.undistort`` without a new camera matrix). For each output pixel we distort its
    normalised coordinates and sample the input there, so no inverse of the model is needed.
    """
    k1, k2, p1, p2, k3 = (list(dist) + [0.0] * 5)[:5]
    h, w = intr.height, intr.width
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    x, y, _ = pixel_directions(u, v, intr.fx, intr.fy, intr.cx, intr.cy).unbind(-1)  # normalised coordinates
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    ud = xd * intr.fx + intr.cx
    vd = yd * intr.fy + intr.cy
    grid = torch.stack([2 * ud / (w - 1) - 1, 2 * vd / (h - 1) - 1], dim=-1)
    return grid[None].float()


#: the keyword options every loader takes besides its own (passed on to :meth:`RGBDDataset._setup`; the table
#: "Common keyword options" of docs/data.md); ``depth_scale`` and ``intrinsics`` are each loader's own
COMMON_OPTIONS = ("crop_size", "crop_edge", "crop_edge_raw", "focal_px", "undistort", "stride", "max_frames")

class RGBDDataset:
    """A sequence of RGB-D frames on disk; ``ds[i]`` reads and processes frame ``i``.

    Subclasses only find the files and poses (or, for frames not stored as image files, give them through
    :meth:`raw_color` / :meth:`raw_depth`, calling :meth:`_select` and :meth:`_set_camera` instead of :meth:`_setup`);
    this class applies the reference processing order
    (docs/data.md, "Common keyword options (every loader)"): colour resized to the depth size, colour undistorted
    (depth is not; it is registered to the colour camera), optional resize to ``crop_size`` (colour bilinear,
    depth nearest), then ``crop_edge`` pixels removed from every border. ``intrinsics`` follow every step.

    Args (common keyword options of every loader):
        crop_size: ``(H, W)`` to resize to, or None.
        focal_px: resize so the focal length becomes about this many pixels (:func:`slam.data.resize.working_size`), when
            ``crop_size`` is not given; None: no resize.
        crop_edge: pixels of the working image to remove from every border after resizing.
        crop_edge_raw: the same counted on the raw image (a sensor's or undistortion's dark rim), scaled with the
            resize and rounded, when ``crop_edge`` is not given.
        undistort: apply the distortion model to colour if the source has one.
        stride: keep every ``stride``-th frame.
        max_frames: keep at most this many frames (after stride).
        depth_scale: override the PNG depth scale (raw value / scale = metres).
    """

    name: str = "rgbd"
    gt_mesh_path: Path | None = None

    def _setup(
        self,
        *,
        root: Path,
        color_paths: list[Path],
        depth_paths: list[Path],
        poses: np.ndarray,
        timestamps: Sequence[float],
        intrinsics: Intrinsics,
        depth_scale: float,
        distortion: Sequence[float] | None = None,
        crop_size: tuple[int, int] | None = None,
        crop_edge: int | None = None,
        crop_edge_raw: int | None = None,
        focal_px: float | None = None,
        undistort: bool = True,
        stride: int = 1,
        max_frames: int | None = None,
        allow_invalid_poses: bool = False,
        pose_source: Path | None = None,
    ) -> None:
        self.root = Path(root)
        if len(color_paths) != len(depth_paths):
            raise SlamInputError(
                f"{self.root}: {len(color_paths)} colour images but {len(depth_paths)} depth images"
            )
        sel = self._select(len(color_paths), poses, timestamps, stride, max_frames, allow_invalid_poses, pose_source)
        self._color_paths = [Path(color_paths[i]) for i in sel]
        self._depth_paths = [Path(depth_paths[i]) for i in sel]
        # fail at open time, not halfway through a run
        for p in self._color_paths + self._depth_paths:
            if not p.is_file():
                raise SlamInputError(f"{p}: image file not found (listed by {self.root})")
        if depth_scale <= 0:
            raise SlamInputError(f"{self.root}: depth scale must be positive, got {depth_scale}")
        self.depth_scale = float(depth_scale)
        self._set_camera(intrinsics, distortion if undistort else None, crop_size, crop_edge, crop_edge_raw, focal_px)
        log.debug("opened %r (raw camera %s, distortion %s)", self, intrinsics, self.distortion)

    def _select(self, n: int, poses, timestamps: Sequence[float], stride: int, max_frames: int | None,
                allow_invalid_poses: bool, pose_source: Path | None) -> np.ndarray:
        """The indices of the frames kept of the ``n`` found (``stride``, ``max_frames``); sets ``_poses`` (from
        ``poses [n, 4, 4]`` camera-to-world, checked rigid) and ``timestamps`` (seconds) of those frames."""
        if n == 0:
            raise SlamInputError(f"{self.root}: no frames found")
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(poses) != n:
            raise SlamInputError(f"{self.root}: {n} frames but {len(poses)} ground-truth poses")
        check_rigid(poses, str(pose_source or self.root), tol=1e-3, allow_nan=allow_invalid_poses)
        if stride < 1:
            raise SlamInputError(f"{self.root}: stride must be >= 1, got {stride}")
        sel = np.arange(0, n, stride)
        if max_frames is not None:
            sel = sel[: int(max_frames)]
        self._poses = torch.tensor(poses[sel], dtype=torch.float32)
        self.timestamps = [float(timestamps[i]) for i in sel]
        return sel

    def _set_camera(self, intrinsics: Intrinsics, distortion: Sequence[float] | None,
                    crop_size: tuple[int, int] | None, crop_edge: int | None = None, crop_edge_raw: int | None = None,
                    focal_px: float | None = None) -> None:
        """The raw camera, the distortion to undo (None: none) and the camera after resizing and cropping (the
        options of the class's text)."""
        self.raw_intrinsics = intrinsics
        self.distortion = tuple(float(d) for d in distortion) if distortion is not None else None
        try:
            self.crop_size, self.crop_edge = resize_and_crop(intrinsics, crop_size, crop_edge, crop_edge_raw, focal_px)
        except SlamInputError as exc:
            raise SlamInputError(f"{self.root}: {exc}") from None
        intr = intrinsics
        if self.crop_size is not None:
            intr = intr.resized(*self.crop_size)
        if self.crop_edge:
            try:
                intr = intr.cropped(self.crop_edge)
            except ValueError as exc:
                raise SlamInputError(f"{self.root}: {exc}") from None
        self.intrinsics = intr
        self._grid = undistort_grid(intrinsics, self.distortion) if self.distortion and any(self.distortion) else None

    # --- sequence protocol -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for {n} frames")
        i = i % n
        return Frame(
            index=i,
            timestamp=self.timestamps[i],
            color=self.load_color(i),
            depth=self.load_depth(i),
            pose=self._poses[i].clone(),
            intrinsics=self.intrinsics,
        )

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    @property
    def gt_poses(self) -> torch.Tensor:
        """``[N, 4, 4]`` float32 camera-to-world ground truth (OpenCV axes); NaN rows where invalid."""
        return self._poses.clone()

    @property
    def valid_poses(self) -> torch.Tensor:
        """``[N]`` bool, True where the ground-truth pose is finite."""
        return torch.isfinite(self._poses).flatten(1).all(dim=1)

    @property
    def color_paths(self) -> list[Path]:
        return list(self._color_paths)

    @property
    def depth_paths(self) -> list[Path]:
        return list(self._depth_paths)

    def __repr__(self) -> str:
        k = self.intrinsics
        return f"{type(self).__name__}({str(self.root)!r}, frames={len(self)}, {k.height}x{k.width}, fx={k.fx:.2f})"

    # --- image processing ---------------------------------------------------------------------------------
    def raw_depth(self, i: int) -> torch.Tensor:
        """Depth of frame ``i`` as stored: ``[h, w]`` float32 metres at the raw camera size, 0 = invalid."""
        raw = read_depth(self._depth_paths[i], (self.raw_intrinsics.height, self.raw_intrinsics.width))
        return torch.from_numpy(raw.astype(np.float32)) / self.depth_scale

    def raw_color(self, i: int) -> np.ndarray:
        """Colour of frame ``i`` as stored: ``[h, w, 3]`` uint8 RGB (any size; :meth:`load_color` resizes it)."""
        return read_color(self._color_paths[i])

    def load_depth(self, i: int) -> torch.Tensor:
        """Depth of frame ``i``: ``[H, W]`` float32 metres, 0 = invalid."""
        depth = self.raw_depth(i)
        if self.crop_size is not None and tuple(depth.shape) != self.crop_size:
            # nearest keeps depth edges sharp and holes as holes
            depth = F.interpolate(depth[None, None], size=self.crop_size, mode="nearest")[0, 0]
        return self._crop(depth)

    def load_color(self, i: int) -> torch.Tensor:
        """Colour of frame ``i``: ``[H, W, 3]`` float32 RGB in [0, 1]."""
        raw = self.raw_color(i)
        img = torch.from_numpy(np.ascontiguousarray(raw)).permute(2, 0, 1)[None].float() / 255.0
        h, w = self.raw_intrinsics.height, self.raw_intrinsics.width
        if img.shape[-2:] != (h, w):
            img = F.interpolate(img, size=(h, w), mode="bilinear", align_corners=False, antialias=True)
        if self._grid is not None:
            img = F.grid_sample(img, self._grid, mode="bilinear", padding_mode="zeros", align_corners=True)
        if self.crop_size is not None and tuple(img.shape[-2:]) != self.crop_size:
            img = F.interpolate(img, size=self.crop_size, mode="bilinear", align_corners=True)
        img = img[0].permute(1, 2, 0).clamp(0.0, 1.0).contiguous()
        return self._crop(img)

    def _crop(self, x: torch.Tensor) -> torch.Tensor:
        e = self.crop_edge
        if e:
            x = x[e:-e, e:-e]
        return x.contiguous()
