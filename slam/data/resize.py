"""The working image of a camera: the size a loader resizes to (from a focal length, or given) and the border it
crops, from the options every loader takes (:class:`slam.data.base.RGBDDataset`)."""

from __future__ import annotations

import math

from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["SIDE_MULTIPLE", "resize_and_crop", "working_size"]

#: the working image's sides are multiples of this many pixels when ``focal_px`` chooses its size
SIDE_MULTIPLE = 8


def working_size(intrinsics: Intrinsics, focal_px: float) -> tuple[int, int]:
    """``(H, W)`` of the working image for a camera: the raw image scaled so its focal length becomes about
    ``focal_px`` pixels, never up (a camera at or below it keeps its size), each side rounded to a multiple of
    :data:`SIDE_MULTIPLE`.

    One focal length for every camera gives every dataset the same angular resolution (degrees per pixel), which is
    what the per-pixel budgets (pixels sampled, image-space edges) were measured at: TUM's Kinect (517 px on 640x480)
    becomes 192x256, Microsoft's 7-Scenes Kinect (585 px) 168x224, Replica's 600 px on 1200x680 232x416."""
    if not (math.isfinite(focal_px) and focal_px > 0):
        raise SlamInputError(f"data option 'focal_px' must be a positive number of pixels, got {focal_px!r}")
    s = float(focal_px) / max(intrinsics.fx, intrinsics.fy)
    if s >= 1.0:
        return intrinsics.height, intrinsics.width
    return tuple(min(side, max(SIDE_MULTIPLE, int(round(side * s / SIDE_MULTIPLE)) * SIDE_MULTIPLE))
                 for side in (intrinsics.height, intrinsics.width))


def resize_and_crop(intrinsics: Intrinsics, crop_size=None, crop_edge: int | None = None,
                    crop_edge_raw: int | None = None, focal_px: float | None = None) -> tuple[tuple | None, int]:
    """The ``(crop_size, crop_edge)`` a loader applies to a raw camera, from the options of :class:`RGBDDataset`:
    ``crop_size`` if given, else the size ``focal_px`` gives (:func:`working_size`), else None (no resize); then
    ``crop_edge`` if given, else ``crop_edge_raw`` scaled by the resize and rounded, else 0."""
    if crop_size is None and focal_px is not None:
        crop_size = working_size(intrinsics, focal_px)
        if crop_size == (intrinsics.height, intrinsics.width):
            crop_size = None  # a camera already at or below the focal length is used as it is
    crop_size = tuple(int(s) for s in crop_size) if crop_size is not None else None
    if crop_edge is None and crop_edge_raw is not None:
        if crop_edge_raw < 0:
            raise SlamInputError(f"data option 'crop_edge_raw' must be >= 0, got {crop_edge_raw}")
        scale = crop_size[1] / intrinsics.width if crop_size is not None else 1.0
        crop_edge = int(round(crop_edge_raw * scale))
    return crop_size, int(crop_edge or 0)
