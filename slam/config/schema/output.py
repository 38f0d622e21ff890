"""What a run writes besides its trajectory: the ``meshing`` and ``evaluation`` sections."""

from __future__ import annotations

from dataclasses import dataclass

from slam.config.declare import COUNT, METRES, NONNEG, POSITIVE, key, num


@dataclass
class MeshingConfig:
    """The mesh: marching cubes inside a visibility hull of the keyframes, then culled to what the frames saw."""

    resolution: float = num(0.01, **METRES, doc="marching-cubes grid spacing in metres (`lrslam mesh --resolution` "
                                                "overrides it)")
    batch: int = num(500000, lo=1, hi=1_000_000_000, doc="points per SDF and colour query while meshing (memory "
                                                         "against calls)")
    hull_scale: float = num(1.02, **POSITIVE, doc=(
        "(ours, without Open3D) the mesh is extracted inside the convex hull of keyframe depth points and cameras, "
        "scaled by this about its centroid"))
    hull_points_per_frame: int = num(2000, **COUNT, doc="random valid depth pixels per keyframe in that hull")
    block_cells: int = num(32, lo=0, hi=4096, doc=(
        "(ours) cells per block edge: marching cubes only in the blocks within `scene.truncation` of back-projected "
        "keyframe depth, welded on the block faces, so memory follows the surface; 0: one dense volume over the "
        "whole marching-cubes bound (the reference)"))
    cull: bool = key(True, "remove the faces of which no processed frame saw a vertex (in front of the camera, inside "
                           "the image)")
    cull_depth_test: bool = key(True, (
        "a vertex counts as seen only at most `scene.truncation` behind the frame's depth, in the mesh's and the "
        "ground truth's culling (false in the presets of noisy depth)"))


@dataclass
class EvaluationConfig:
    """Reconstruction metrics against a ground-truth mesh (accuracy, completion, Depth L1), where there is one."""

    samples: int = num(200000, lo=1, hi=1_000_000_000, doc="points sampled on each mesh for accuracy and completion")
    icp: bool = key(True, "ICP-align the reconstruction to the ground-truth mesh before the metrics")
    depth_l1_views: int = num(1000, **NONNEG, doc="random views of Depth L1; 0: skip it")
