"""Rendering one view: exact z-depth by ray casting, colour with anti-aliasing at edges, and the Kinect-like
sensor model that degrades the depth."""

from __future__ import annotations

import numpy as np

from slam.data.synthetic.scene import SynthScene, cast_rays
from slam.data.synthetic.textures import albedo, shade
from slam.data.types import Intrinsics


def _pixel_dirs(intr: Intrinsics, pose: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    v, u = np.meshgrid(np.arange(intr.height, dtype=np.float64), np.arange(intr.width, dtype=np.float64), indexing="ij")
    u = u.reshape(-1)[None] + offsets[:, 0:1]
    v = v.reshape(-1)[None] + offsets[:, 1:2]
    cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)  # [S, P, 3]
    return cam @ pose[:3, :3].T


def render_frame(scene: SynthScene, pose: np.ndarray, intr: Intrinsics, supersample: int = 1):
    """Render one noise-free view.

    Args:
        pose: ``[4, 4]`` camera-to-world (OpenCV axes). intr: the camera.
    Returns:
        color ``[H, W, 3]`` float64 in [0, 1], depth ``[H, W]`` metres (z-depth), normal-dot-view ``[H, W]``
        (|cos| of the incidence angle, used by the sensor model), material id ``[H, W]``.
    """
    o = pose[:3, 3]
    centre = _pixel_dirs(intr, pose, np.zeros((1, 2)))[0]
    t, n, mat = cast_rays(scene, o, centre)
    h, w = intr.height, intr.width
    depth = t.reshape(h, w)
    cos = np.abs((n * centre).sum(1)) / np.linalg.norm(centre, axis=1)
    if supersample > 1:
        # Anti-alias where it matters: pixels whose 4 neighbours lie on the same plane and material get
        # one sample (the texture is smooth at pixel scale), the rest (occluding edges, creases, curved
        # surfaces; ~20 % of pixels) the mean of supersample^2 rays. 3x cheaper than supersampling all.
        s = supersample
        p_c = o + t[:, None] * centre
        col = np.empty((h * w, 3))
        flat = _planar_interior(p_c.reshape(h, w, 3), n.reshape(h, w, 3), mat.reshape(h, w)).reshape(-1)
        fi = np.flatnonzero(flat)
        col[fi] = albedo(scene, p_c[fi], mat[fi]) * shade(scene, p_c[fi], n[fi])
        ri = np.flatnonzero(~flat)
        if len(ri):
            g = (np.arange(s) + 0.5) / s - 0.5
            offs = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
            sub = _pixel_dirs(intr, pose, offs)[:, ri].reshape(-1, 3)
            tr, nr, mr = cast_rays(scene, o, sub)
            pts = o + tr[:, None] * sub
            cs = albedo(scene, pts, mr) * shade(scene, pts, nr)
            col[ri] = cs.reshape(len(offs), len(ri), 3).mean(0)
    else:
        pts = o + t[:, None] * centre
        col = albedo(scene, pts, mat) * shade(scene, pts, n)
    return np.clip(col, 0, 1).reshape(h, w, 3), depth, cos.reshape(h, w), mat.reshape(h, w)


def _planar_interior(p: np.ndarray, n: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """``[H, W]`` True where a pixel and its 4 neighbours hit the same material on the same plane."""
    off = (p * n).sum(-1)
    ok = np.zeros(mat.shape, bool)
    ok[1:-1, 1:-1] = True
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        sl = (slice(1 + dy, mat.shape[0] - 1 + dy), slice(1 + dx, mat.shape[1] - 1 + dx))
        c = (slice(1, -1), slice(1, -1))
        ok[c] &= (mat[sl] == mat[c]) & (np.abs(n[sl] - n[c]).max(-1) < 1e-5) & (np.abs(off[sl] - off[c]) < 1e-4)
    return ok


def sensor_depth(depth: np.ndarray, cos: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Kinect-like degradation of an exact depth map (metres, 0 = hole)."""
    from scipy import ndimage

    z = depth + rng.normal(0.0, 1.0, depth.shape) * (0.0012 + 0.0019 * (depth - 0.4) ** 2)
    invalid = (depth < 0.4) | (depth > 4.5) | (cos < 0.12)
    # depth discontinuities: the structured-light pattern is lost on both sides of an occluding edge
    gy = np.abs(np.diff(depth, axis=0, prepend=depth[:1]))
    gx = np.abs(np.diff(depth, axis=1, prepend=depth[:, :1]))
    edge = np.maximum(gx, gy) > 0.04 * depth
    invalid |= ndimage.binary_dilation(edge, iterations=1)
    blobs = rng.random(depth.shape) < 0.002
    invalid |= ndimage.binary_dilation(blobs, iterations=2)
    z[invalid] = 0.0
    return z
