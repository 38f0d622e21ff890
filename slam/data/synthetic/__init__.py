"""A procedural indoor room rendered analytically into an RGB-D sequence: the project's built-in dataset.

Two scenes (``SynthConfig.scene``): the room, and the walk (:mod:`~slam.data.synthetic.walk`: three connected
rooms along 20 m, walked through and back in 2100 frames with Kinect-like depth; :func:`walk_config`,
:func:`walk_sequence`).

The room is a 4 m x 4 m x 2.5 m room (world frame: z up, floor at z = 0, walls at x, y = +-2) with a table,
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

The parts: :mod:`~slam.data.synthetic.config` (:class:`SynthConfig`), :mod:`~slam.data.synthetic.scene` (the
room's primitives and materials, ray casting), :mod:`~slam.data.synthetic.textures` (albedo and shading),
:mod:`~slam.data.synthetic.camera` (the path), :mod:`~slam.data.synthetic.render` (one view, the sensor model),
:mod:`~slam.data.synthetic.mesh` (the ground-truth mesh) and :mod:`~slam.data.synthetic.sequence` (writing,
caching, :data:`GENERATOR_VERSION`).
"""

from slam.data.synthetic.camera import camera_path
from slam.data.synthetic.config import SCENES, WALK_FRAMES, SynthConfig, walk_config
from slam.data.synthetic.mesh import scene_mesh
from slam.data.synthetic.render import render_frame
from slam.data.synthetic.scene import EVAL_CAMERA_BOX, ROOM_MAX, ROOM_MIN, SynthScene, build_scene
from slam.data.synthetic.sequence import (
    DEPTH_SCALE,
    GENERATOR_VERSION,
    cache_root,
    default_sequence,
    generate,
    scene_and_path,
    walk_sequence,
)
from slam.data.synthetic.textures import albedo
from slam.data.synthetic.walk import EVAL_CAMERA_BOX_WALK, build_walk_scene, free_space_distance, walk_path

__all__ = [
    "SynthConfig",
    "SynthScene",
    "generate",
    "default_sequence",
    "cache_root",
    "camera_path",
    "render_frame",
    "build_scene",
    "scene_mesh",
    "albedo",
    "GENERATOR_VERSION",
    "DEPTH_SCALE",
    "EVAL_CAMERA_BOX",
    "ROOM_MIN",
    "ROOM_MAX",
    "SCENES",
    "WALK_FRAMES",
    "walk_config",
    "walk_sequence",
    "walk_path",
    "build_walk_scene",
    "free_space_distance",
    "scene_and_path",
    "EVAL_CAMERA_BOX_WALK",
]
