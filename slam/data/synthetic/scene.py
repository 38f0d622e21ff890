"""The room's geometry and materials, and ray casting against it.

A 4 m x 4 m x 2.5 m room (world frame: z up, floor at z = 0, walls at x, y = +-2) holding a table, a cabinet, a
shelf, a sofa, a pillar and a few spheres/cylinders: analytic boxes, spheres and vertical cylinders, each with a
material (a pair of colours and a texture scale, drawn from the seed). Rays ``o + t d`` have unnormalised ``d``
with unit camera z, so the hit parameter ``t`` is the z-depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ROOM_MIN = np.array([-2.0, -2.0, 0.0])
ROOM_MAX = np.array([2.0, 2.0, 2.5])
#: ``camera_box`` for :func:`slam.eval.depth_l1` on this room: free space around the camera loop (the
#: reference's Replica rule would put some virtual cameras above the ceiling here)
EVAL_CAMERA_BOX = ((-1.2, -1.2, 0.9), (1.2, 1.2, 2.0))


@dataclass
class SynthScene:
    """Analytic primitives (world metres, z up) and per-material colours.

    boxes: list of (min [3], max [3], material); spheres: (centre [3], radius, material);
    cylinders: vertical, (centre_xy [2], radius, z0, z1, material). Materials 0..5 are the room faces
    (-x, +x, -y, +y, floor, ceiling). ``room_min`` / ``room_max`` bound the enclosing box seen from inside (the
    room's by default; the walk's building is larger).
    """

    boxes: list
    spheres: list
    cylinders: list
    colors_a: np.ndarray  # [M, 3] first colour of each material
    colors_b: np.ndarray  # [M, 3] second colour
    scales: np.ndarray  # [M] texture frequency multiplier
    lattice: np.ndarray  # [6, G, G, G] value-noise tables
    light: np.ndarray  # [3] point light position
    room_min: np.ndarray = field(default_factory=lambda: ROOM_MIN.copy())
    room_max: np.ndarray = field(default_factory=lambda: ROOM_MAX.copy())


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
    colors_a, colors_b, scales, lattice = material_tables(rng, 18)
    return SynthScene(b, spheres, cylinders, colors_a, colors_b, scales, lattice, np.array([0.3, -0.2, 2.3]))


def material_tables(rng: np.random.Generator, m: int):
    """Colours, texture scales and noise tables of ``m`` materials (the first 6 the room faces, paler):
    ``(colors_a [m, 3], colors_b [m, 3], scales [m], lattice [6, 32, 32, 32])``."""
    # pleasant but distinct hues: sample in HSV-like space, walls paler, furniture more saturated
    hue = rng.uniform(0, 1, m)
    sat = np.where(np.arange(m) < 6, rng.uniform(0.15, 0.35, m), rng.uniform(0.35, 0.75, m))
    val = np.where(np.arange(m) < 6, rng.uniform(0.7, 0.9, m), rng.uniform(0.55, 0.9, m))
    colors_a = _hsv_to_rgb(hue, sat, val)
    colors_b = _hsv_to_rgb((hue + rng.uniform(0.1, 0.4, m)) % 1.0, np.clip(sat + 0.2, 0, 1), val * 0.45)
    scales = rng.uniform(0.8, 1.6, m)
    lattice = rng.uniform(0.0, 1.0, (6, 32, 32, 32)).astype(np.float32)
    return colors_a, colors_b, scales, lattice


def _hsv_to_rgb(h, s, v):
    h6 = (h * 6.0)[:, None]
    k = (np.array([5.0, 3.0, 1.0])[None] + h6) % 6.0
    return v[:, None] - v[:, None] * s[:, None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


# ray casting (rays o + t d with unnormalised d, so t is the camera z-depth)
_EPS = 1e-6


def _candidates(o: np.ndarray, d: np.ndarray, dd: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Indices of rays that pass within ``radius`` of ``centre`` in front of the camera (a cheap pre-test:
    most primitives cover a small part of the image, so the exact test runs on few rays)."""
    oc = centre - o
    b = d @ oc
    c = oc @ oc - radius * radius
    return np.flatnonzero((b * b - dd * c > 0) & ((b > 0) | (c < 0)))


def cast_rays(scene: SynthScene, o: np.ndarray, d: np.ndarray):
    """Nearest hit of rays ``o [3] + t d [P, 3]``: returns ``t [P]``, normal ``[P, 3]``, material ``[P]``."""
    # float32 halves the memory traffic; z-depth error stays ~1e-7 relative, far below the 0.15 mm PNG step
    d = d.astype(np.float32)
    o = o.astype(np.float32)
    dd = (d * d).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        hits = _room_hits(o, d, inv, scene.room_min, scene.room_max)
        for bmin, bmax, mid in scene.boxes:
            _hit_box(hits, o, d, dd, inv, bmin, bmax, mid)
        for c, r, mid in scene.spheres:
            _hit_sphere(hits, o, d, dd, c, r, mid)
        for cyl in scene.cylinders:
            _hit_cylinder(hits, o, d, dd, inv, cyl, (scene.room_min[2], scene.room_max[2]))
    return hits


# the hit_* helpers update the nearest hits so far, ``(t [P], normal [P, 3], material [P])``, in place where a
# primitive is hit in front of them; they run inside cast_rays' errstate (rays parallel to a face divide by 0)
def _room_hits(o: np.ndarray, d: np.ndarray, inv: np.ndarray, rmin: np.ndarray, rmax: np.ndarray):
    """The room (box ``rmin``..``rmax``), seen from inside: every ray's exit face, ``(t [P], normal [P, 3],
    material [P])``."""
    p = len(d)
    ar = np.arange(p)
    tfar = np.maximum((rmin - o) * inv, (rmax - o) * inv)
    axis = np.argmin(tfar, axis=1)
    t_best = tfar[ar, axis]
    sign = np.sign(d[ar, axis])
    normal = np.zeros((p, 3), np.float32)
    normal[ar, axis] = -sign
    # faces: -x 0, +x 1, -y 2, +y 3, floor 4, ceiling 5
    mat = np.where(axis == 2, np.where(sign < 0, 4, 5), 2 * axis + (sign > 0))
    return t_best, normal, mat


def _hit_box(hits, o, d, dd, inv, bmin, bmax, mid) -> None:
    t_best, normal, mat = hits
    idx = _candidates(o, d, dd, (bmin + bmax) / 2, float(np.linalg.norm(bmax - bmin)) / 2 + 1e-6)
    if not len(idx):
        return
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


def _hit_sphere(hits, o, d, dd, c, r, mid) -> None:
    t_best, normal, mat = hits
    idx = _candidates(o, d, dd, c, r)
    if not len(idx):
        return
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


def _hit_cylinder(hits, o, d, dd, inv, cyl, floor_ceiling) -> None:
    """A vertical cylinder ``(centre_xy, radius, z0, z1, material)``: its side, then its caps (those not hidden in
    the floor or ceiling, at the heights ``floor_ceiling``)."""
    t_best, normal, mat = hits
    cxy, r, z0, z1, mid = cyl
    centre = np.array([cxy[0], cxy[1], (z0 + z1) / 2])
    idx = _candidates(o, d, dd, centre, float(np.hypot(r, (z1 - z0) / 2)) + 1e-6)
    if not len(idx):
        return
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
        if zc <= floor_ceiling[0] + 1e-9 or zc >= floor_ceiling[1] - 1e-9:
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
