"""The walk: three connected rooms along a 20 m building, walked through and back at hand-held speed.

The building spans x in [0, 20] m, y in [-2, 2] m, z in [0, 2.6] m (world z up). Two partition walls at x = 6.5
and x = 13.5 leave a 2.8 m wide opening in the middle (wall stubs 0.6 m from each side wall, a lintel above
2.1 m), so the three rooms are connected. Furniture stands against the side walls (cabinets, a sofa, a shelf,
sideboards, spheres, a lamp) and a floor-to-ceiling pillar stands in the middle of each room.

The camera walks a closed loop at 1.5 m height: along the lane y = -0.7 to the far end, a half turn of radius
0.7 m, back along y = +0.7 and a half turn to the start (39.6 m in ``loop_frames`` = 2100 frames, 70 s at 30 Hz:
0.57 m/s on average, 0.45-0.68 m/s with a gait-like speed change), looking ahead with gentle head rotation (yaw
+-11 deg, pitch -8 +- 3 deg, roll +-1.5 deg) and a 1 cm step bob. Depth is the Kinect-like sensor model of
:func:`slam.data.synthetic.render.sensor_depth` (nothing past 4.5 m: the far rooms are out of range).
"""

from __future__ import annotations

import numpy as np

from slam.data.synthetic.camera import look_poses
from slam.data.synthetic.config import SynthConfig
from slam.data.synthetic.scene import SynthScene, material_tables

WALK_MIN = np.array([0.0, -2.0, 0.0])
WALK_MAX = np.array([20.0, 2.0, 2.6])
#: x of the partition walls between the rooms
PARTITIONS = (6.5, 13.5)
#: the loop the camera walks: lanes at y = +-LANE between the turn centres at x = TURN_X[0], TURN_X[1]
LANE, TURN_X, HEIGHT = 0.7, (1.2, 18.8), 1.5
#: ``camera_box`` for :func:`slam.eval.depth_l1` on the walk: free space around the path
EVAL_CAMERA_BOX_WALK = ((0.6, -1.0, 1.1), (19.4, 1.0, 1.9))


def _box(lo, hi, mid):
    return (np.array(lo, float), np.array(hi, float), mid)


def build_walk_scene(seed: int = 0) -> SynthScene:
    """The fixed building with seed-dependent colours and textures (materials 0..5 the building's faces)."""
    rng = np.random.default_rng([seed, 7])
    b = []
    for k, x in enumerate(PARTITIONS):
        m = 6 + k
        b += [_box([x - 0.06, -2.0, 0.0], [x + 0.06, -1.4, 2.6], m),
              _box([x - 0.06, 1.4, 0.0], [x + 0.06, 2.0, 2.6], m),
              _box([x - 0.06, -1.4, 2.1], [x + 0.06, 1.4, 2.6], m)]
    b += [
        _box([1.0, 1.55, 0.0], [2.6, 2.0, 1.0], 8),  # room 1: cabinet on +y
        _box([3.4, -2.0, 0.0], [5.2, -1.6, 0.8], 9),  # room 1: sideboard on -y
        _box([7.4, 1.5, 0.0], [9.6, 2.0, 0.45], 10),  # room 2: sofa seat and back on +y
        _box([7.4, 1.82, 0.45], [9.6, 2.0, 0.95], 10),
        _box([10.2, -2.0, 0.0], [11.6, -1.62, 1.9], 11),  # room 2: tall shelf on -y
        _box([14.4, -2.0, 0.0], [16.0, -1.55, 1.1], 12),  # room 3: cabinet on -y
        _box([15.0, 1.6, 0.0], [16.6, 2.0, 0.7], 13),  # room 3: low box on +y
        _box([17.2, -2.0, 0.0], [18.6, -1.6, 0.75], 9),  # room 3: sideboard on -y
    ]
    spheres = [
        (np.array([4.3, -1.8, 0.98]), 0.18, 14),  # ball on the sideboard
        (np.array([12.8, 1.6, 0.35]), 0.35, 15),  # big ball in room 2's corner
        (np.array([15.8, 1.8, 0.85]), 0.15, 14),  # ball on the low box
        (np.array([1.8, 1.78, 1.15]), 0.15, 16),  # ball on the cabinet
    ]
    cylinders = [(np.array([x, 0.0]), 0.18, 0.0, 2.6, 17) for x in (3.6, 10.0, 16.6)]  # pillars
    cylinders += [(np.array([17.8, -1.8]), 0.08, 0.75, 1.2, 18),  # lamp base on the sideboard
                  (np.array([8.5, 1.75]), 0.12, 0.95, 1.3, 18)]  # pot on the sofa back
    colors_a, colors_b, scales, lattice = material_tables(rng, 19)
    light = np.array([10.0, 0.0, 2.5])
    return SynthScene(b, spheres, cylinders, colors_a, colors_b, scales, lattice, light, WALK_MIN.copy(),
                      WALK_MAX.copy())


def _loop_point(s: np.ndarray):
    """Position ``[N, 2]`` and heading ``[N]`` at arc length ``s`` (any real; periodic) along the loop."""
    straight = TURN_X[1] - TURN_X[0]
    arc = np.pi * LANE
    total = 2 * straight + 2 * arc
    s = np.mod(s, total)
    xy = np.zeros((len(s), 2))
    head = np.zeros(len(s))
    a = s < straight  # along y = -LANE towards +x
    xy[a] = np.stack([TURN_X[0] + s[a], np.full(a.sum(), -LANE)], 1)
    t = s - straight
    b = (t >= 0) & (t < arc)  # half turn around the far centre
    ang = -np.pi / 2 + t[b] / LANE
    xy[b] = np.stack([TURN_X[1] + LANE * np.cos(ang), LANE * np.sin(ang)], 1)
    head[b] = t[b] / LANE
    t = s - straight - arc
    c = (t >= 0) & (t < straight)  # back along y = +LANE
    xy[c] = np.stack([TURN_X[1] - t[c], np.full(c.sum(), LANE)], 1)
    head[c] = np.pi
    t = s - 2 * straight - arc
    d = t >= 0  # half turn around the near centre
    ang = np.pi / 2 + t[d] / LANE
    xy[d] = np.stack([TURN_X[0] + LANE * np.cos(ang), LANE * np.sin(ang)], 1)
    head[d] = np.pi + t[d] / LANE
    return xy, head, total


def walk_path(cfg: SynthConfig) -> np.ndarray:
    """``[frames, 4, 4]`` camera-to-world poses (OpenCV axes) of the walk (``loop_frames`` frames a loop)."""
    rng = np.random.default_rng([cfg.seed, 1])
    ph = rng.uniform(0, 2 * np.pi, 8)
    k = np.arange(cfg.frames, dtype=np.float64)
    total = _loop_point(np.zeros(1))[2]
    # gait-like speed change (+-20 %) and a small sideways sway; the heading follows the path's tangent
    s = total * k / cfg.loop_frames + 0.15 * np.sin(2 * np.pi * k / 240 + ph[0])
    xy, head, _ = _loop_point(s)
    side = 0.06 * np.sin(2 * np.pi * k / 170 + ph[1])
    x = xy[:, 0] - side * np.sin(head)
    y = xy[:, 1] + side * np.cos(head)
    z = HEIGHT + 0.01 * np.sin(2 * np.pi * k / 17 + ph[2]) + 0.04 * np.sin(2 * np.pi * k / 310 + ph[3])
    yaw = np.unwrap(head) + 0.2 * np.sin(2 * np.pi * k / 150 + ph[4])
    pitch = -0.14 + 0.05 * np.sin(2 * np.pi * k / 190 + ph[5])
    roll = 0.025 * np.sin(2 * np.pi * k / 130 + ph[6])
    return look_poses(np.stack([x, y, z], 1), yaw, pitch, roll)


def free_space_distance(scene: SynthScene, p: np.ndarray) -> np.ndarray:
    """``[P]`` distance (m) from points ``p [P, 3]`` to the nearest surface, negative inside a solid or outside the
    enclosing box (exact for the room box and the spheres, a lower bound near box and cylinder edges)."""
    dist = np.minimum(p - scene.room_min, scene.room_max - p).min(1)
    for bmin, bmax, _ in scene.boxes:
        q = np.maximum(bmin - p, p - bmax)
        dist = np.minimum(dist, np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0))
    for c, r, _ in scene.spheres:
        dist = np.minimum(dist, np.linalg.norm(p - c, axis=1) - r)
    for cxy, r, z0, z1, _ in scene.cylinders:
        q = np.stack([np.linalg.norm(p[:, :2] - cxy, axis=1) - r, np.maximum(z0 - p[:, 2], p[:, 2] - z1)], 1)
        dist = np.minimum(dist, np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0))
    return dist
