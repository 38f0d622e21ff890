"""RGB-D datasets: one frame type and one sequence interface for every source.

Every loader returns :class:`Frame` objects with colour ``[H, W, 3]`` float32 in [0, 1], depth ``[H, W]``
float32 metres (0 = invalid), a ``[4, 4]`` camera-to-world ground-truth pose in the **OpenCV camera
convention** (x right, y down, z forward; no axis flips anywhere), :class:`Intrinsics`, a timestamp in
seconds and the frame index. See ``docs/data.md``.

Sources: Replica (and the synthetic room), TUM RGB-D (and TUM-format recordings of any camera,
:class:`TUMWriter`), ScanNet, 7-Scenes, ROS 1 and 2 bags (:class:`BagDataset`, the ``bags`` extra): one entry
each in :data:`DATASETS` (:mod:`slam.data.registry`, which says how to add one). Datasets: ``len(ds)``, ``ds[i]``, ``ds.intrinsics``, ``ds.timestamps``,
``ds.gt_poses [N, 4, 4]``, ``ds.name``, ``ds.gt_mesh_path`` (Path or None).
"""

from slam.data.bag import BagDataset
from slam.data.base import RGBDDataset
from slam.data.loader import detect_layout, load_dataset
from slam.data.registry import DATASETS, REFERENCE_OPTIONS, DatasetKind
from slam.data.replica import ReplicaDataset
from slam.data.scannet import ScanNetDataset
from slam.data.sevenscenes import SevenScenesDataset
from slam.data.tum import TUMDataset
from slam.data.tum_writer import TUMWriter
from slam.data.types import Frame, Intrinsics

__all__ = [
    "Frame",
    "Intrinsics",
    "RGBDDataset",
    "ReplicaDataset",
    "TUMDataset",
    "TUMWriter",
    "ScanNetDataset",
    "SevenScenesDataset",
    "BagDataset",
    "load_dataset",
    "detect_layout",
    "DATASETS",
    "DatasetKind",
    "REFERENCE_OPTIONS",
]
