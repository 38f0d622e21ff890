"""The pinhole camera, one way: pixel directions and back-projection (OpenCV convention, docs/data.md).

``d = ((u - cx) / fx, (v - cy) / fy, 1)``, **not normalised**: the ray parameter is the camera-axis depth, so a
depth reading ``z`` puts the point at ``z * d``. Every module that turns pixels and depth into points (rendering,
keyframe overlap, the visibility hull, ICP, the Depth L1 metric) uses these two functions.
"""

from __future__ import annotations

import torch


def pixel_directions(u: torch.Tensor, v: torch.Tensor, fx: float, fy: float, cx: float, cy: float) -> torch.Tensor:
    """Camera-frame ray directions ``[..., 3]`` with unit z (OpenCV) for pixel coordinates ``u, v`` ``[...]``
    (columns, rows; any float dtype, kept)."""
    return torch.stack(((u - cx) / fx, (v - cy) / fy, torch.ones_like(u)), -1)


def backproject(u: torch.Tensor, v: torch.Tensor, z: torch.Tensor, fx: float, fy: float, cx: float,
                cy: float) -> torch.Tensor:
    """Camera-frame points ``[..., 3]`` (metres) of pixels ``u, v`` ``[...]`` at camera-axis depths ``z`` ``[...]``
    (0 gives the camera centre)."""
    return pixel_directions(u, v, fx, fy, cx, cy) * z[..., None]


def sample_pixels(
    height: int, width: int, n: int, edge_h: int = 0, edge_w: int = 0, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Uniform random pixels *with replacement* in ``[edge_h, H - edge_h) x [edge_w, W - edge_w)``.

    Edges too large for the image are reduced so that at least the central pixel remains.

    Returns:
        ``(v, u)`` ``[n]`` long row and column indices (CPU).
    """
    edge_h = max(0, min(int(edge_h), (height - 1) // 2))
    edge_w = max(0, min(int(edge_w), (width - 1) // 2))
    v = torch.randint(edge_h, height - edge_h, (n,), generator=generator)
    u = torch.randint(edge_w, width - edge_w, (n,), generator=generator)
    return v, u
