"""Keyframe store and ESLAM's overlap-based mapping window (eslam-pipeline.md §5)."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from slam.pose import pose_to_matrix


@dataclass
class Keyframe:
    """One stored keyframe: ``color [H, W, 3]``, ``depth [H, W]`` (metres), its estimated pose as ``[7]`` (q, t)
    camera-to-world (refined by BA)."""

    index: int
    color: torch.Tensor
    depth: torch.Tensor
    pose: torch.Tensor


@dataclass
class KeyframeStore:
    """Ordered list of keyframes (by frame index)."""

    frames: list[Keyframe] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frames)

    def add(self, kf: Keyframe) -> None:
        self.frames.append(kf)

    def poses(self) -> torch.Tensor:
        """``[K, 7]`` current estimated poses."""
        return torch.stack([k.pose for k in self.frames]) if self.frames else torch.zeros(0, 7)


def overlapping_keyframes(
    depth: torch.Tensor,
    c2w: torch.Tensor,
    keyframe_c2w: torch.Tensor,
    fx: float, fy: float, cx: float, cy: float, height: int, width: int,
    n_pixels: int = 50,
    n_samples: int = 8,
    margin: int = 20,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Which keyframes see points of the current frame (ESLAM 'overlap' selection, steps 1-3).

    Casts ``n_pixels`` random valid-depth pixels, puts ``n_samples`` evenly spaced points on each in
    ``[0.8 D, D + 0.5]``, projects them into every keyframe and reports the keyframes that have at least one
    point in front of the camera and inside the image with a ``margin`` px border.

    Args:
        depth: ``[H, W]`` current depth (metres, 0 invalid).
        c2w: ``[4, 4]`` current camera-to-world.
        keyframe_c2w: ``[K, 4, 4]`` keyframe camera-to-world (OpenCV).

    Returns:
        ``[K]`` bool mask.
    """
    K = keyframe_c2w.shape[0]
    valid = torch.nonzero(depth > 0)
    if K == 0 or valid.shape[0] == 0:
        return torch.zeros(K, dtype=torch.bool)
    pick = torch.randint(0, valid.shape[0], (n_pixels,), generator=generator)
    vu = valid[pick]
    v = vu[:, 0].to(depth.dtype)
    u = vu[:, 1].to(depth.dtype)
    D = depth[vu[:, 0], vu[:, 1]]
    t = torch.linspace(0.0, 1.0, n_samples, dtype=depth.dtype)
    z = 0.8 * D[:, None] + (D[:, None] + 0.5 - 0.8 * D[:, None]) * t  # [P, S]
    dirs = torch.stack(((u - cx) / fx, (v - cy) / fy, torch.ones_like(u)), -1)
    pts_cam = dirs[:, None, :] * z[..., None]  # [P, S, 3]
    pts = pts_cam.reshape(-1, 3) @ c2w[:3, :3].T + c2w[:3, 3]
    w2c = torch.linalg.inv(keyframe_c2w)  # [K, 4, 4]
    pc = torch.einsum("kij,pj->kpi", w2c[:, :3, :3], pts) + w2c[:, None, :3, 3]
    zc = pc[..., 2]
    zs = torch.where(zc.abs() < 1e-5, torch.full_like(zc, 1e-5), zc)
    uu = fx * pc[..., 0] / zs + cx
    vv = fy * pc[..., 1] / zs + cy
    inside = (uu > margin) & (uu < width - margin) & (vv > margin) & (vv < height - margin) & (zc > 0)
    return inside.any(-1)


def select_window(
    n_keyframes: int,
    overlap: torch.Tensor,
    window_size: int = 20,
    generator: torch.Generator | None = None,
) -> list[int]:
    """ESLAM's window (steps 4-5): up to ``window_size - 1`` random overlapping keyframes among all but the
    last two, plus the last two keyframes. The caller adds the current frame.

    Args:
        n_keyframes: number of stored keyframes.
        overlap: ``[n_keyframes]`` bool (only entries before the last two are used).
        window_size: ESLAM's ``mapping_window_size`` W.

    Returns:
        Sorted keyframe positions (indices into the store).
    """
    older = max(n_keyframes - 2, 0)
    cand = [i for i in range(older) if bool(overlap[i])]
    if len(cand) > window_size - 1:
        perm = torch.randperm(len(cand), generator=generator)[: window_size - 1]
        cand = [cand[int(i)] for i in perm]
    chosen = set(cand) | set(range(older, n_keyframes))
    return sorted(chosen)


def keyframe_matrices(poses: torch.Tensor) -> torch.Tensor:
    """``[K, 7]`` -> ``[K, 4, 4]`` (no gradient)."""
    with torch.no_grad():
        return pose_to_matrix(poses)
