"""A procedural indoor room rendered analytically into an RGB-D sequence: the project's built-in dataset.

The scene is a 4 m x 4 m x 2.5 m room (world frame: z up, floor at z = 0, walls at x, y = +-2) with a table,
a cabinet, a shelf, a sofa, a pillar and a few spheres/cylinders. Every surface carries a colour texture that
is a function of the 3D world point (value noise at three scales mixed between two colours per material,
times fixed Lambertian shading from a ceiling light), so the images are multi-view consistent and rich
enough for photometric tracking, with low-frequency content that keeps the gradient basin wide.

The camera moves like a hand-held sensor at 30 Hz on a loop of radius ~0.9 m around the room centre, looking
inward and slightly down, with slow sinusoidal wobble in position, yaw, pitch and roll (about 1.4 cm and
about 1 degree per frame; ``loop_frames`` frames close the loop). Depth is exact z-depth from ray casting
(boxes, spheres, vertical cylinders, the room box), optionally with Gaussian noise or a Kinect-like noise
and hole model. Poses are exact.

:func:`generate` writes the Replica layout that :class:`slam.data.ReplicaDataset` reads, plus ``mesh.ply``
(ground truth built from trimesh primitives that match the analytic surfaces), ``cam.json`` and
``synth.json`` (the config). :func:`default_sequence` generates the default once into a cache folder.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = [
    "SynthConfig",
    "SynthScene",
    "generate",
    "default_sequence",
    "camera_path",
    "render_frame",
    "build_scene",
    "scene_mesh",
    "GENERATOR_VERSION",
    "DEPTH_SCALE",
    "EVAL_CAMERA_BOX",
]

log = logging.getLogger(__name__)

#: bump when the output of :func:`generate` changes for the same config, so caches regenerate
GENERATOR_VERSION = 3
#: the Replica depth PNG scale: metres = value / 6553.5 (65535 <-> 10 m, 0.15 mm steps)
DEPTH_SCALE = 6553.5

ROOM_MIN = np.array([-2.0, -2.0, 0.0])
ROOM_MAX = np.array([2.0, 2.0, 2.5])
#: ``camera_box`` for :func:`slam.eval.depth_l1` on this room: free space around the camera loop (the
#: reference's Replica rule would put some virtual cameras above the ceiling here)
EVAL_CAMERA_BOX = ((-1.2, -1.2, 0.9), (1.2, 1.2, 2.0))


@dataclass
class SynthConfig:
    """Synthetic sequence options.

    Attributes:
        seed: texture, colour and noise seed (geometry is fixed; the path wobble phases depend on it).
        frames: number of frames (30 Hz timestamps ``i / 30``).
        height, width: image size in pixels.
        focal_scale: ``fx = fy = focal_scale * width`` (0.6 gives a ~80 deg horizontal field of view).
        depth_noise_sigma: std (metres) of i.i.d. Gaussian noise added to valid depth.
        sensor_holes: Kinect-like depth: depth-dependent noise ``0.0012 + 0.0019 (z - 0.4)^2`` m, no depth
            closer than 0.4 m or past 4.5 m, holes at depth edges, at grazing angles and in random blobs.
        color_noise_sigma: std of i.i.d. Gaussian colour noise (colour in [0, 1]).
        loop_frames: frames per full loop around the room (sets the speed: ~1.4 cm, ~0.9 deg per frame).
        path_radius: radius (m) of the camera loop around the room centre.
        supersample: colour anti-aliasing: pixels at occluding edges, creases and curved surfaces average
            ``supersample^2`` rays (flat interiors take one, the texture being smooth at pixel scale); depth
            always uses the centre ray.
    """

    seed: int = 0
    frames: int = 120
    height: int = 120
    width: int = 160
    focal_scale: float = 0.6
    depth_noise_sigma: float = 0.0
    sensor_holes: bool = False
    color_noise_sigma: float = 0.0
    loop_frames: int = 400
    path_radius: float = 0.9
    supersample: int = 2

    def intrinsics(self) -> Intrinsics:
        f = self.focal_scale * self.width
        return Intrinsics(f, f, (self.width - 1) / 2.0, (self.height - 1) / 2.0, self.height, self.width)

    def validate(self) -> None:
        if self.frames < 1 or self.height < 8 or self.width < 8 or self.supersample < 1 or self.loop_frames < 8:
            raise SlamInputError(f"synthetic config out of range: {self}")
        if self.depth_noise_sigma < 0 or self.color_noise_sigma < 0:
            raise SlamInputError("synthetic config: noise sigmas must be >= 0")


# --------------------------------------------------------------------------------------------------------
# scene description
# --------------------------------------------------------------------------------------------------------
@dataclass
class SynthScene:
    """Analytic primitives (world metres, z up) and per-material colours.

    boxes: list of (min [3], max [3], material); spheres: (centre [3], radius, material);
    cylinders: vertical, (centre_xy [2], radius, z0, z1, material). Materials 0..5 are the room faces
    (-x, +x, -y, +y, floor, ceiling).
    """

    boxes: list
    spheres: list
    cylinders: list
    colors_a: np.ndarray  # [M, 3] first colour of each material
    colors_b: np.ndarray  # [M, 3] second colour
    scales: np.ndarray  # [M] texture frequency multiplier
    lattice: np.ndarray  # [6, G, G, G] value-noise tables
    light: np.ndarray  # [3] point light position


def build_scene(seed: int = 0) -> SynthScene:
    """The fixed room layout with seed-dependent colours and textures."""
    rng = np.random.default_rng(seed)
    b = []
    # table: top + 4 legs, centred in the room
    b.append((np.array([-0.45, -0.3, 0.71]), np.array([0.45, 0.3, 0.76]), 6))
    for sx in (-1, 1):
        for sy in (-1, 1):
            cx, cy = sx * 0.39, sy * 0.24
            b.append((np.array([cx - 0.03, cy - 0.03, 0.0]), np.array([cx + 0.03, cy + 0.03, 0.71]), 7))
    b.append((np.array([0.12, -0.22, 0.76]), np.array([0.34, -0.04, 0.92]), 9))  # box on the table
    b.append((np.array([1.45, -0.9, 0.0]), np.array([2.0, 0.3, 1.1]), 10))  # cabinet on +x wall
    b.append((np.array([-2.0, -1.3, 0.0]), np.array([-1.62, 0.1, 1.9]), 12))  # shelf on -x wall
    b.append((np.array([-0.6, 1.5, 0.0]), np.array([0.9, 2.0, 0.45]), 13))  # sofa seat on +y wall
    b.append((np.array([-0.6, 1.82, 0.45]), np.array([0.9, 2.0, 0.95]), 13))  # sofa back
    b.append((np.array([-0.3, -2.0, 0.0]), np.array([0.8, -1.75, 0.75]), 16))  # low sideboard on -y wall
    spheres = [
        (np.array([-0.15, 0.08, 0.91]), 0.15, 8),  # ball on the table
        (np.array([1.7, -0.2, 1.28]), 0.18, 14),  # ball on the cabinet
        (np.array([1.55, 1.55, 0.35]), 0.35, 17),  # big ball in a corner
    ]
    cylinders = [
        (np.array([-1.6, 1.6]), 0.2, 0.0, 2.5, 11),  # pillar, floor to ceiling
        (np.array([0.3, 0.15]), 0.06, 0.76, 1.0, 15),  # vase on the table
        (np.array([0.3, -1.85]), 0.08, 0.75, 1.15, 15),  # lamp base on the sideboard
    ]
    m = 18
    # pleasant but distinct hues: sample in HSV-like space, walls paler, furniture more saturated
    hue = rng.uniform(0, 1, m)
    sat = np.where(np.arange(m) < 6, rng.uniform(0.15, 0.35, m), rng.uniform(0.35, 0.75, m))
    val = np.where(np.arange(m) < 6, rng.uniform(0.7, 0.9, m), rng.uniform(0.55, 0.9, m))
    colors_a = _hsv_to_rgb(hue, sat, val)
    colors_b = _hsv_to_rgb((hue + rng.uniform(0.1, 0.4, m)) % 1.0, np.clip(sat + 0.2, 0, 1), val * 0.45)
    scales = rng.uniform(0.8, 1.6, m)
    lattice = rng.uniform(0.0, 1.0, (6, 32, 32, 32)).astype(np.float32)
    return SynthScene(b, spheres, cylinders, colors_a, colors_b, scales, lattice, np.array([0.3, -0.2, 2.3]))


def _hsv_to_rgb(h, s, v):
    h6 = (h * 6.0)[:, None]
    k = (np.array([5.0, 3.0, 1.0])[None] + h6) % 6.0
    return v[:, None] - v[:, None] * s[:, None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


# --------------------------------------------------------------------------------------------------------
# ray casting (rays o + t d with unnormalised d, so t is the camera z-depth)
# --------------------------------------------------------------------------------------------------------
_EPS = 1e-6


def _candidates(o: np.ndarray, d: np.ndarray, dd: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Indices of rays that pass within ``radius`` of ``centre`` in front of the camera (a cheap pre-test:
    most primitives cover a small part of the image, so the exact test runs on few rays)."""
    oc = centre - o
    b = d @ oc
    c = oc @ oc - radius * radius
    return np.flatnonzero((b * b - dd * c > 0) & ((b > 0) | (c < 0)))


def _cast(scene: SynthScene, o: np.ndarray, d: np.ndarray):
    """Nearest hit of rays ``o [3] + t d [P, 3]``: returns ``t [P]``, normal ``[P, 3]``, material ``[P]``."""
    # float32 halves the memory traffic; z-depth error stays ~1e-7 relative, far below the 0.15 mm PNG step
    d = d.astype(np.float32)
    o = o.astype(np.float32)
    p = len(d)
    ar = np.arange(p)
    dd = (d * d).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        # room, seen from inside: the exit face
        tfar = np.maximum((ROOM_MIN - o) * inv, (ROOM_MAX - o) * inv)
        axis = np.argmin(tfar, axis=1)
        t_best = tfar[ar, axis]
        sign = np.sign(d[ar, axis])
        normal = np.zeros((p, 3), np.float32)
        normal[ar, axis] = -sign
        # faces: -x 0, +x 1, -y 2, +y 3, floor 4, ceiling 5
        mat = np.where(axis == 2, np.where(sign < 0, 4, 5), 2 * axis + (sign > 0))
        for bmin, bmax, mid in scene.boxes:
            idx = _candidates(o, d, dd, (bmin + bmax) / 2, float(np.linalg.norm(bmax - bmin)) / 2 + 1e-6)
            if not len(idx):
                continue
            di, ii = d[idx], inv[idx]
            t1 = (bmin - o) * ii
            t2 = (bmax - o) * ii
            tn = np.minimum(t1, t2)
            ax = np.argmax(tn, axis=1)
            tmin = tn[np.arange(len(idx)), ax]
            tmax = np.maximum(t1, t2).min(axis=1)
            hit = (tmin <= tmax) & (tmin > _EPS) & (tmin < t_best[idx])
            if hit.any():
                k = idx[hit]
                t_best[k] = tmin[hit]
                n = np.zeros((len(k), 3))
                n[np.arange(len(k)), ax[hit]] = -np.sign(di[hit, ax[hit]])
                normal[k] = n
                mat[k] = mid
        for c, r, mid in scene.spheres:
            idx = _candidates(o, d, dd, c, r)
            if not len(idx):
                continue
            di = d[idx]
            oc = o - c
            bq = 2.0 * di @ oc
            cq = oc @ oc - r * r
            disc = bq * bq - 4 * dd[idx] * cq
            t = (-bq - np.sqrt(np.maximum(disc, 0.0))) / (2 * dd[idx])
            hit = (disc > 0) & (t > _EPS) & (t < t_best[idx])
            if hit.any():
                k = idx[hit]
                t_best[k] = t[hit]
                normal[k] = (o + t[hit, None] * di[hit] - c) / r
                mat[k] = mid
        for cxy, r, z0, z1, mid in scene.cylinders:
            centre = np.array([cxy[0], cxy[1], (z0 + z1) / 2])
            idx = _candidates(o, d, dd, centre, float(np.hypot(r, (z1 - z0) / 2)) + 1e-6)
            if not len(idx):
                continue
            di, ii = d[idx], inv[idx]
            ox, oy = o[0] - cxy[0], o[1] - cxy[1]
            a = di[:, 0] ** 2 + di[:, 1] ** 2
            bq = 2 * (di[:, 0] * ox + di[:, 1] * oy)
            cq = ox * ox + oy * oy - r * r
            disc = bq * bq - 4 * a * cq
            t = (-bq - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
            z = o[2] + t * di[:, 2]
            hit = (disc > 0) & (t > _EPS) & (t < t_best[idx]) & (z >= z0) & (z <= z1)
            if hit.any():
                k = idx[hit]
                t_best[k] = t[hit]
                hp = o + t[hit, None] * di[hit]
                n = np.zeros((len(k), 3))
                n[:, 0] = (hp[:, 0] - cxy[0]) / r
                n[:, 1] = (hp[:, 1] - cxy[1]) / r
                normal[k] = n
                mat[k] = mid
            for zc, nz in ((z1, 1.0), (z0, -1.0)):
                if zc <= ROOM_MIN[2] + 1e-9 or zc >= ROOM_MAX[2] - 1e-9:
                    continue  # cap hidden in floor/ceiling
                t = (zc - o[2]) * ii[:, 2]
                hx = o[0] + t * di[:, 0] - cxy[0]
                hy = o[1] + t * di[:, 1] - cxy[1]
                hit = (t > _EPS) & (t < t_best[idx]) & (hx * hx + hy * hy <= r * r)
                if hit.any():
                    k = idx[hit]
                    t_best[k] = t[hit]
                    normal[k] = np.array([0.0, 0.0, nz])
                    mat[k] = mid
    return t_best, normal, mat


def _value_noise(table: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] at points ``p [P, 3]`` (lattice units) from a periodic ``[G, G, G]`` table.

    Trilinear interpolation at smoothstep-warped cell coordinates: C1 across cells, so no grid creases.
    """
    from scipy import ndimage

    f = np.floor(p)
    w = p - f
    q = f + w * w * (3.0 - 2.0 * w)
    return ndimage.map_coordinates(table, q.T, order=1, mode="grid-wrap")


def albedo(scene: SynthScene, p: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """Surface colour ``[P, 3]`` in [0, 1] at world points ``p [P, 3]`` of materials ``mat [P]``."""
    s = scene.scales[mat][:, None].astype(np.float32)
    # a per-material offset decorrelates materials that share a lattice
    q = p.astype(np.float32) * s + mat[:, None].astype(np.float32) * np.array([3.7, 5.3, 1.9], np.float32)
    low = _value_noise(scene.lattice[0], q * 1.6)  # ~60 cm blobs: wide photometric basin
    mid = _value_noise(scene.lattice[1], q * 5.0)  # ~20 cm
    high = _value_noise(scene.lattice[2], q * 14.0)  # ~7 cm detail
    mix = np.clip(0.55 * low + 0.3 * mid + 0.15 * high, 0, 1)
    mix = np.clip((mix - 0.5) * 2.2 + 0.5, 0.0, 1.0)  # more contrast than a plain noise sum
    shade = 0.7 + 0.6 * np.abs(high - 0.5)  # fine brightness detail without another lookup
    col = scene.colors_a[mat] * (1.0 - mix[:, None]) + scene.colors_b[mat] * mix[:, None]
    return np.clip(col * shade[:, None], 0.0, 1.0)


def _shade(scene: SynthScene, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    to_l = scene.light - p
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    lam = np.clip((n * to_l).sum(1, keepdims=True) / dist, 0.0, 1.0)
    return 0.45 + 0.75 * lam / (1.0 + 0.08 * dist**2)


# --------------------------------------------------------------------------------------------------------
# camera path
# --------------------------------------------------------------------------------------------------------
def camera_path(cfg: SynthConfig) -> np.ndarray:
    """``[frames, 4, 4]`` camera-to-world poses (OpenCV axes) of the hand-held-like loop."""
    rng = np.random.default_rng([cfg.seed, 1])
    ph = rng.uniform(0, 2 * np.pi, 8)
    k = np.arange(cfg.frames, dtype=np.float64)
    th = -np.pi / 2 + 2 * np.pi * k / cfg.loop_frames
    r = cfg.path_radius + 0.06 * np.sin(2 * th + ph[0])
    x = r * np.cos(th) + 0.015 * np.sin(k * 2 * np.pi / 47 + ph[1])
    y = r * np.sin(th) + 0.015 * np.sin(k * 2 * np.pi / 53 + ph[2])
    z = 1.35 + 0.08 * np.sin(3 * th + ph[3]) + 0.01 * np.sin(k * 2 * np.pi / 41 + ph[4])
    yaw = th + np.pi + 0.30 * np.sin(2 * th + ph[5])
    pitch = -0.32 + 0.07 * np.sin(3.7 * th + ph[6])
    roll = 0.04 * np.sin(5 * th + ph[7])
    poses = np.tile(np.eye(4), (cfg.frames, 1, 1))
    fwd = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], 1)
    right = np.cross(fwd, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(fwd, right)
    cr, sr = np.cos(roll)[:, None], np.sin(roll)[:, None]
    right2 = cr * right + sr * down
    down2 = -sr * right + cr * down
    poses[:, :3, 0] = right2
    poses[:, :3, 1] = down2
    poses[:, :3, 2] = fwd
    poses[:, :3, 3] = np.stack([x, y, z], 1)
    return poses


# --------------------------------------------------------------------------------------------------------
# rendering
# --------------------------------------------------------------------------------------------------------
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
    t, n, mat = _cast(scene, o, centre)
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
        col[fi] = albedo(scene, p_c[fi], mat[fi]) * _shade(scene, p_c[fi], n[fi])
        ri = np.flatnonzero(~flat)
        if len(ri):
            g = (np.arange(s) + 0.5) / s - 0.5
            offs = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
            sub = _pixel_dirs(intr, pose, offs)[:, ri].reshape(-1, 3)
            tr, nr, mr = _cast(scene, o, sub)
            pts = o + tr[:, None] * sub
            cs = albedo(scene, pts, mr) * _shade(scene, pts, nr)
            col[ri] = cs.reshape(len(offs), len(ri), 3).mean(0)
    else:
        pts = o + t[:, None] * centre
        col = albedo(scene, pts, mat) * _shade(scene, pts, n)
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


def _sensor_depth(depth: np.ndarray, cos: np.ndarray, rng: np.random.Generator) -> np.ndarray:
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


# --------------------------------------------------------------------------------------------------------
# ground-truth mesh
# --------------------------------------------------------------------------------------------------------
def scene_mesh(scene: SynthScene, max_edge: float = 0.1, drop_hidden: bool = True):
    """Ground-truth ``trimesh.Trimesh`` of the scene (room faces inward), edges split to <= ``max_edge`` m.

    Short edges keep vertex-based culling (:func:`slam.eval.cull_mesh`) fine-grained. With ``drop_hidden``
    faces that no camera inside the room can ever see are removed: faces inside or touching another solid
    (floor under furniture, box bottoms, a vase's base on the table, the wall behind the shelf) and object
    faces lying on the room boundary. Like a scanned GT mesh, it then holds only surfaces that exist to a
    sensor. Vertex colours are the texture albedo.
    """
    import trimesh

    parts = []
    room = trimesh.creation.box(extents=ROOM_MAX - ROOM_MIN)
    room.apply_translation((ROOM_MAX + ROOM_MIN) / 2)
    room.invert()  # normals point into the room, the side the camera sees
    parts.append(room)
    for bmin, bmax, _ in scene.boxes:
        m = trimesh.creation.box(extents=bmax - bmin)
        m.apply_translation((bmax + bmin) / 2)
        parts.append(m)
    for c, r, _ in scene.spheres:
        m = trimesh.creation.icosphere(subdivisions=4, radius=r)
        m.apply_translation(c)
        parts.append(m)
    for cxy, r, z0, z1, _ in scene.cylinders:
        m = trimesh.creation.cylinder(radius=r, height=z1 - z0, sections=96)
        m.apply_translation([cxy[0], cxy[1], (z0 + z1) / 2])
        parts.append(m)
    meshes = []
    for k, m in enumerate(parts):
        v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=max_edge)
        if drop_hidden:
            centroids = v[f].mean(axis=1)
            hidden = _inside_solids(scene, centroids, skip=k - 1)
            if k > 0:
                hidden |= np.any((centroids < ROOM_MIN + 1e-3) | (centroids > ROOM_MAX - 1e-3), axis=1)
            f = f[~hidden]
        part = trimesh.Trimesh(v, f, process=False)
        part.remove_unreferenced_vertices()
        meshes.append(part)
    mesh = trimesh.util.concatenate(meshes)
    # colour by the nearest analytic surface (room faces by which wall they lie on)
    mats = _vertex_materials(scene, mesh.vertices)
    col = albedo(scene, mesh.vertices, mats)
    mesh.visual.vertex_colors = np.concatenate([np.round(col * 255), np.full((len(col), 1), 255)], 1).astype(np.uint8)
    return mesh


def _inside_solids(scene: SynthScene, p: np.ndarray, skip: int = -1, eps: float = 1e-3) -> np.ndarray:
    """``[P]`` True where points lie inside or within ``eps`` of any solid except number ``skip``
    (solids numbered boxes, then spheres, then cylinders)."""
    inside = np.zeros(len(p), bool)
    k = 0
    for bmin, bmax, _ in scene.boxes:
        if k != skip:
            inside |= np.all((p >= bmin - eps) & (p <= bmax + eps), axis=1)
        k += 1
    for c, r, _ in scene.spheres:
        if k != skip:
            inside |= np.linalg.norm(p - c, axis=1) <= r + eps
        k += 1
    for cxy, r, z0, z1, _ in scene.cylinders:
        if k != skip:
            inside |= (np.linalg.norm(p[:, :2] - cxy, axis=1) <= r + eps) & (p[:, 2] >= z0 - eps) & (p[:, 2] <= z1 + eps)
        k += 1
    return inside


def _vertex_materials(scene: SynthScene, v: np.ndarray) -> np.ndarray:
    best = np.full(len(v), np.inf)
    mat = np.zeros(len(v), np.int64)
    # room faces
    dists = np.stack([v[:, 0] - ROOM_MIN[0], ROOM_MAX[0] - v[:, 0], v[:, 1] - ROOM_MIN[1], ROOM_MAX[1] - v[:, 1],
                      v[:, 2] - ROOM_MIN[2], ROOM_MAX[2] - v[:, 2]], 1)
    best = np.abs(dists).min(1)
    mat = np.abs(dists).argmin(1)
    for bmin, bmax, mid in scene.boxes:
        q = np.maximum(np.maximum(bmin - v, v - bmax), 0)
        inside = np.minimum(np.maximum(bmin - v, v - bmax).max(1), 0)
        dd = np.abs(np.linalg.norm(q, axis=1) + inside)
        upd = dd < best - 1e-9
        best[upd], mat[upd] = dd[upd], mid
    for c, r, mid in scene.spheres:
        dd = np.abs(np.linalg.norm(v - c, axis=1) - r)
        upd = dd < best - 1e-9
        best[upd], mat[upd] = dd[upd], mid
    for cxy, r, z0, z1, mid in scene.cylinders:
        rad = np.abs(np.linalg.norm(v[:, :2] - cxy, axis=1) - r)
        ax = np.maximum(np.maximum(z0 - v[:, 2], v[:, 2] - z1), 0)
        dd = np.hypot(rad, ax)
        upd = dd < best - 1e-9
        best[upd], mat[upd] = dd[upd], mid
    return mat


# --------------------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------------------
def _config_record(cfg: SynthConfig) -> dict:
    return {"generator_version": GENERATOR_VERSION, "config": dataclasses.asdict(cfg)}


def generate(out_dir, cfg: SynthConfig | None = None, *, overwrite: bool = True) -> Path:
    """Render the sequence and write it in the Replica layout into ``out_dir``; returns ``out_dir``.

    Files: ``results/frame%06d.png`` (8-bit RGB, lossless), ``results/depth%06d.png`` (uint16, metres *
    6553.5, 0 = hole), ``traj.txt`` (16 floats per line, row-major camera-to-world, OpenCV axes),
    ``mesh.ply`` (ground truth), ``cam.json`` (intrinsics, depth scale), ``synth.json`` (config).
    Deterministic: the same config gives byte-identical images.
    """
    import imageio.v3 as iio

    cfg = cfg or SynthConfig()
    cfg.validate()
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise SlamInputError(f"{out}: folder exists and is not empty")
        if not (out / "synth.json").exists():
            raise SlamInputError(f"{out}: folder exists, is not empty and is not a synthetic sequence; refusing to overwrite")
        shutil.rmtree(out / "results", ignore_errors=True)
    t0 = time.perf_counter()
    (out / "results").mkdir(parents=True, exist_ok=True)
    scene = build_scene(cfg.seed)
    intr = cfg.intrinsics()
    poses = camera_path(cfg)
    for i, pose in enumerate(poses):
        color, depth, cos, _ = render_frame(scene, pose, intr, cfg.supersample)
        rng = np.random.default_rng([cfg.seed, 2, i])
        if cfg.sensor_holes:
            depth = _sensor_depth(depth, cos, rng)
        if cfg.depth_noise_sigma > 0:
            valid = depth > 0
            depth = np.where(valid, depth + rng.normal(0.0, cfg.depth_noise_sigma, depth.shape), 0.0)
        if cfg.color_noise_sigma > 0:
            color = color + rng.normal(0.0, cfg.color_noise_sigma, color.shape)
        col8 = np.round(np.clip(color, 0, 1) * 255).astype(np.uint8)
        d16 = np.round(np.clip(depth, 0, 65535 / DEPTH_SCALE) * DEPTH_SCALE).astype(np.uint16)
        # low zlib effort: 3x faster writes for ~10 % larger files
        iio.imwrite(out / "results" / f"frame{i:06d}.png", col8, compress_level=1)
        iio.imwrite(out / "results" / f"depth{i:06d}.png", d16, compress_level=1)
    np.savetxt(out / "traj.txt", poses.reshape(len(poses), 16), fmt="%.10f")
    mesh = scene_mesh(scene)
    mesh.export(out / "mesh.ply")
    cam = {**intr.as_dict(), "depth_scale": DEPTH_SCALE, "name": f"synthetic_seed{cfg.seed}",
           "axes": "OpenCV (x right, y down, z forward); traj.txt is camera-to-world"}
    (out / "cam.json").write_text(json.dumps(cam, indent=2) + "\n")
    (out / "synth.json").write_text(json.dumps(_config_record(cfg), indent=2) + "\n")
    log.info("synthetic sequence: %d frames %dx%d in %.1f s -> %s", cfg.frames, cfg.height, cfg.width,
             time.perf_counter() - t0, out)
    return out


def cache_root() -> Path:
    """``$LRSLAM_CACHE`` or ``~/.cache/lrslam``."""
    return Path(os.environ.get("LRSLAM_CACHE", Path.home() / ".cache" / "lrslam")).expanduser()


def default_sequence(cache_dir=None, cfg: SynthConfig | None = None) -> Path:
    """Folder of the default synthetic sequence, generated on first use and cached.

    The folder is ``<cache_dir or cache_root()>/synthetic_default`` (``synthetic_<seed>_<frames>_<H>x<W>_...``
    for a non-default ``cfg``). It is regenerated if its ``synth.json`` differs from the requested config or
    generator version. Generation writes to a temporary sibling folder and renames it, so concurrent
    callers never see a half-written sequence.
    """
    cfg = cfg or SynthConfig()
    root = Path(cache_dir).expanduser() if cache_dir is not None else cache_root()
    name = "synthetic_default" if cfg == SynthConfig() else "synthetic_" + _config_tag(cfg)
    target = root / name
    want = _config_record(cfg)
    if _holds(target, want):
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=root))
    try:
        generate(tmp, cfg)
        if _holds(target, want):
            # another process finished first: keep its copy, which readers may already hold open
            shutil.rmtree(tmp, ignore_errors=True)
            return target
        if target.exists():
            old = root / f".{name}.old.{os.getpid()}"
            try:
                target.rename(old)
                shutil.rmtree(old, ignore_errors=True)
            except OSError:
                pass
        try:
            tmp.rename(target)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not _holds(target, want):
                raise SlamInputError(f"{target}: cannot write the synthetic sequence into the cache") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def _holds(folder: Path, record: dict) -> bool:
    try:
        return json.loads((folder / "synth.json").read_text()) == record and (folder / "mesh.ply").exists()
    except (OSError, ValueError):
        return False


def _config_tag(cfg: SynthConfig) -> str:
    import hashlib

    blob = json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode()
    return f"{cfg.seed}_{cfg.frames}_{cfg.height}x{cfg.width}_" + hashlib.sha1(blob).hexdigest()[:8]
