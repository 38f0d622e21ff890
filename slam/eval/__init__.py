"""Evaluation: trajectory error (ATE), reconstruction metrics, mesh culling and plots.

Units are metres everywhere (the reference papers quote cm; convert only for display).
Poses are camera-to-world ``[4, 4]`` in the OpenCV camera convention (x right, y down, z forward),
as in :mod:`slam.data`.
"""

from slam.eval.ate import ATEResult, ate, ate_from_files, umeyama
from slam.eval.trajectory import associate, read_tum_trajectory, write_tum_trajectory

__all__ = [
    "ATEResult",
    "ate",
    "ate_from_files",
    "umeyama",
    "associate",
    "read_tum_trajectory",
    "write_tum_trajectory",
]
