"""Evaluation: trajectory error (ATE), reconstruction metrics, mesh culling and plots.

Units are metres everywhere (the reference papers quote cm; convert only for display).
Poses are camera-to-world ``[4, 4]`` in the OpenCV camera convention (x right, y down, z forward),
as in :mod:`slam.data`. See ``docs/evaluation.md``.
"""

from slam.eval.ate import ATEResult, ate, ate_from_files, umeyama
from slam.eval.culling import cull_mesh, visible_vertices
from slam.eval.mesh_metrics import align_mesh, depth_l1, icp_align, load_mesh, reconstruction_metrics, render_depth
from slam.eval.plots import plot_trajectory
from slam.eval.trajectory import associate, frame_steps, read_tum_trajectory, write_tum_trajectory

__all__ = [
    "ATEResult",
    "ate",
    "ate_from_files",
    "umeyama",
    "associate",
    "frame_steps",
    "read_tum_trajectory",
    "write_tum_trajectory",
    "reconstruction_metrics",
    "depth_l1",
    "icp_align",
    "align_mesh",
    "load_mesh",
    "render_depth",
    "cull_mesh",
    "visible_vertices",
    "plot_trajectory",
]
