"""The frame and camera types every dataset returns.

Conventions (one set for every source; loaders convert to it):

* Camera axes: **OpenCV** -- x right, y down, z forward (the optical axis). A pixel ``(u, v)`` (column, row,
  pixel centres at integer coordinates) back-projects to the camera-frame direction
  ``((u - cx) / fx, (v - cy) / fy, 1)``, so a depth value is the z coordinate (not the ray length).
* Poses: camera-to-world ``[4, 4]`` rigid matrices, ``x_world = T @ x_cam``. This is what TUM ground truth,
  ScanNet ``pose/*.txt`` and NICE-SLAM's Replica ``traj.txt`` already store, so no axis flip happens anywhere
  (ESLAM flips columns 1 and 2 internally to OpenGL; we do not).
* Units: metres, seconds; colour in [0, 1] RGB.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["Intrinsics", "Frame"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels for an image of ``height x width`` pixels (pixel centres at integers)."""

    fx: float
    fy: float
    cx: float
    cy: float
    height: int
    width: int

    def scaled(self, sx: float, sy: float) -> "Intrinsics":
        """Intrinsics after resizing the image by ``sx`` horizontally and ``sy`` vertically.

        Scales fx, cx by ``sx`` and fy, cy by ``sy`` (the reference loaders' rule, which keeps ESLAM's
        published working intrinsics, e.g. TUM fr1_desk fx = 413.84 after 640 -> 512).
        """
        return Intrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=self.cx * sx,
            cy=self.cy * sy,
            height=int(round(self.height * sy)),
            width=int(round(self.width * sx)),
        )

    def resized(self, height: int, width: int) -> "Intrinsics":
        """Intrinsics after resizing the image to exactly ``height x width`` pixels."""
        out = self.scaled(width / self.width, height / self.height)
        return Intrinsics(out.fx, out.fy, out.cx, out.cy, int(height), int(width))

    def cropped(self, edge: int) -> "Intrinsics":
        """Intrinsics after removing ``edge`` pixels from every border (cx, cy -= edge; H, W -= 2 edge)."""
        edge = int(edge)
        if edge < 0 or 2 * edge >= min(self.height, self.width):
            raise ValueError(f"crop edge {edge} does not fit a {self.height}x{self.width} image")
        return Intrinsics(self.fx, self.fy, self.cx - edge, self.cy - edge, self.height - 2 * edge, self.width - 2 * edge)

    @property
    def K(self) -> torch.Tensor:
        """``[3, 3]`` float32 camera matrix."""
        return torch.tensor(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=torch.float32
        )

    def as_dict(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "height": self.height, "width": self.width}


@dataclass
class Frame:
    """One RGB-D frame.

    Attributes:
        index: position in the dataset (0-based, after any stride).
        timestamp: seconds (dataset clock; synthetic and Replica use ``index / 30``).
        color: ``[H, W, 3]`` float32 RGB in [0, 1].
        depth: ``[H, W]`` float32 metres along the optical axis; 0 marks an invalid pixel.
        pose: ``[4, 4]`` float32 ground-truth camera-to-world, OpenCV axes; all NaN if the source has no
            valid pose for this frame (ScanNet).
        intrinsics: the camera for ``color``/``depth`` after resizing and cropping.
    """

    index: int
    timestamp: float
    color: torch.Tensor
    depth: torch.Tensor
    pose: torch.Tensor
    intrinsics: Intrinsics

    @property
    def has_valid_pose(self) -> bool:
        return bool(torch.isfinite(self.pose).all())
