"""What a keyframe keeps for loop closure: ORB keypoints and descriptors (OpenCV), the keypoints' points from the
depth, and a subsampled depth cloud with normals for ICP. About 40 kB a keyframe, whatever the image size."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: ORB works on a patch of 31 pixels: images narrower than this are upsampled before detection, so a 160-pixel-wide
#: working image still yields features (the keypoints are scaled back to working-image pixels)
MIN_FEATURE_WIDTH = 320


@dataclass
class KeyframeFeatures:
    """One keyframe's loop-closure data.

    Attributes:
        k: the frame's position in the processed sequence.
        pose: ``[4, 4]`` camera-to-world when it was taken (metres, OpenCV camera), float64.
        keypoints: ``[N, 2]`` float32 pixel coordinates (u, v) in the working image.
        descriptors: ``[N, 32]`` uint8 ORB descriptors.
        points: ``[N, 3]`` float32 camera-frame points (metres) of the keypoints; NaN where the depth is invalid.
        cloud: ``[M, 3]`` float32 camera-frame depth points (metres), subsampled on a pixel grid.
        normals: ``[M, 3]`` float32 unit normals of ``cloud`` (from the depth image's neighbours), facing the camera.
    """

    k: int
    pose: np.ndarray
    keypoints: np.ndarray
    descriptors: np.ndarray
    points: np.ndarray
    cloud: np.ndarray
    normals: np.ndarray

    def state_dict(self) -> dict:
        import torch

        return {"k": self.k, **{name: torch.from_numpy(np.ascontiguousarray(getattr(self, name)))
                                for name in ("pose", "keypoints", "descriptors", "points", "cloud", "normals")}}

    @classmethod
    def from_state_dict(cls, d: dict) -> "KeyframeFeatures":
        return cls(int(d["k"]), *(d[name].numpy() for name in ("pose", "keypoints", "descriptors", "points", "cloud",
                                                              "normals")))


def _gray8(color: np.ndarray) -> np.ndarray:
    """``[H, W, 3]`` RGB in [0, 1] -> ``[H, W]`` uint8 grey."""
    g = color[..., 0] * 0.299 + color[..., 1] * 0.587 + color[..., 2] * 0.114
    return np.clip(g * 255.0 + 0.5, 0, 255).astype(np.uint8)


def depth_cloud(depth: np.ndarray, intrinsics, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points and normals of every ``step``-th pixel of ``depth [H, W]`` (metres, 0 invalid).

    Normals come from the cross product of the neighbours ``step`` pixels right and down; pixels whose neighbours
    are invalid or farther than 10 % of the depth (an occluding edge) are left out.

    Returns:
        ``([M, 3], [M, 3])`` float32 points (metres) and unit normals facing the camera.
    """
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    h, w = depth.shape
    v, u = np.mgrid[0:h - step:step, 0:w - step:step]
    z = depth[v, u]
    zr, zd = depth[v, u + step], depth[v + step, u]
    ok = (z > 0) & (zr > 0) & (zd > 0) & (np.abs(zr - z) < 0.1 * z) & (np.abs(zd - z) < 0.1 * z)

    def point(uu, vv, zz):
        return np.stack(((uu - cx) / fx * zz, (vv - cy) / fy * zz, zz), -1)

    p = point(u, v, z)[ok]
    n = np.cross(point(u + step, v, zr)[ok] - p, point(u, v + step, zd)[ok] - p)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    keep = norm[:, 0] > 1e-12
    p, n = p[keep], n[keep] / norm[keep]
    n *= -np.sign(np.sum(n * p, axis=1, keepdims=True))  # towards the camera
    return p.astype(np.float32), n.astype(np.float32)


def extract(k: int, pose: np.ndarray, color: np.ndarray, depth: np.ndarray, intrinsics, n_features: int = 500,
            cloud_points: int = 3000) -> KeyframeFeatures:
    """The loop-closure data of one keyframe.

    Args:
        k: position in the processed sequence; pose: ``[4, 4]`` camera-to-world.
        color: ``[H, W, 3]`` RGB in [0, 1]; depth: ``[H, W]`` metres (0 invalid); intrinsics: of that image.
        n_features: ORB keypoints at most; cloud_points: about this many ICP points (a pixel grid).
    """
    import cv2

    h, w = depth.shape
    scale = max(1.0, MIN_FEATURE_WIDTH / w)
    gray = _gray8(color)
    mask = (depth > 0).astype(np.uint8)
    if scale > 1.0:
        size = (round(w * scale), round(h * scale))
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_LINEAR)
        mask = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
    # local contrast: dark, low-contrast frames (a dim room, the synthetic walk) otherwise give few repeatable corners
    gray = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(4, 4)).apply(gray)
    orb = cv2.ORB_create(nfeatures=n_features, scaleFactor=1.2, nlevels=4, edgeThreshold=19, patchSize=19,
                         fastThreshold=10)
    # only where there is depth: a keypoint without depth can be matched but never gives the candidate's 3-D point
    kps, desc = orb.detectAndCompute(gray, mask)
    if desc is None or not kps:
        uv = np.zeros((0, 2), np.float32)
        desc = np.zeros((0, 32), np.uint8)
    else:
        uv = (np.array([kp.pt for kp in kps], np.float32) + 0.5) / scale - 0.5
    ui = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
    vi = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
    z = depth[vi, ui].astype(np.float32)
    pts = np.stack(((uv[:, 0] - intrinsics.cx) / intrinsics.fx * z, (uv[:, 1] - intrinsics.cy) / intrinsics.fy * z,
                    z), -1).astype(np.float32)
    pts[z <= 0] = np.nan
    step = max(1, int(np.sqrt(h * w / max(cloud_points, 1))))
    cloud, normals = depth_cloud(depth, intrinsics, step)
    return KeyframeFeatures(k, np.asarray(pose, np.float64), uv.astype(np.float32), desc, pts, cloud, normals)
