"""The datasets the loaders read: :data:`DATASETS`, name -> :class:`DatasetKind`, the one list that layout
detection, :func:`~slam.data.load_dataset`, a config's ``data.kind``, :data:`REFERENCE_OPTIONS` and
``lrslam download`` derive from (as :data:`tdfields.KINDS` is for field kinds).

Adding a dataset: a module ``slam/data/<name>.py`` holding its loader (an :class:`~slam.data.base.RGBDDataset`
subclass) and a ``looks_like(root) -> bool`` probe, plus one line in :data:`DATASETS` below. Detection tries the
probes in the order of :data:`DATASETS`; the first that accepts a folder (or file: a ROS 1 bag) names its layout.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from slam.data import bag, replica, scannet, sevenscenes, tum
from slam.data.base import COMMON_OPTIONS
from slam.errors import SlamInputError

__all__ = ["DATASETS", "REFERENCE_OPTIONS", "DatasetKind", "container_kind", "dataset_kind"]


@dataclass(frozen=True)
class DatasetKind:
    """One dataset the loaders read.

    Attributes:
        name: its name in a config's ``data.kind``, ``load_dataset(kind=...)`` and ``lrslam download``.
        loader: the loader class: ``loader(path, **options)`` opens a folder (a file for a ROS 1 bag).
        looks_like: ``looks_like(root) -> bool`` for an existing folder or file. None for a dataset named but never
            detected, whose folders have the layout of ``same_layout_as`` (the synthetic room: a Replica folder).
        layout: what a folder of it holds, as the error for an unrecognised folder lists it.
        reference_options: the loader options that reproduce the reference (ESLAM) configs' image processing;
            None where no reference config exists.
        download: ``"fetch"``: ``lrslam download`` fetches it (:mod:`slam.data.download` holds where from);
            ``"request"``: its authors give access on request, ``lrslam download`` says how; None: neither.
        same_layout_as: see ``looks_like``.
        hint: ``hint(root) -> str | None``: the message for a folder close to this layout but not of it (a
            7-Scenes scene folder instead of one of its sequences); asked only when no probe accepts a folder.
        container: a file format that holds a recording of any camera (ROS bags), not one dataset's layout: a
            preset of any ``data.kind`` reads it as ``data.kind: auto`` would, with the preset's options.
    """

    name: str
    loader: type
    looks_like: Callable[[Path], bool] | None
    layout: str = ""
    reference_options: Mapping[str, Any] | None = None
    download: str | None = None
    same_layout_as: str | None = None
    hint: Callable[[Path], str | None] | None = None
    container: bool = False

    @property
    def options(self) -> tuple[str, ...]:
        """The keyword options ``loader(path, **options)`` takes: its own keyword parameters and the common ones
        (:data:`slam.data.base.COMMON_OPTIONS`), sorted."""
        own = [p.name for p in inspect.signature(self.loader.__init__).parameters.values()
               if p.kind is inspect.Parameter.KEYWORD_ONLY]
        return tuple(sorted({*own, *COMMON_OPTIONS}))

    @property
    def detected_as(self) -> str:
        """The name :func:`~slam.data.detect_layout` gives a folder of this dataset."""
        return self.same_layout_as or self.name


#: every dataset, in detection order
DATASETS: dict[str, DatasetKind] = {d.name: d for d in (
    DatasetKind("replica", replica.ReplicaDataset, replica.looks_like, "Replica results/ + traj.txt",
                reference_options={}, download="fetch"),
    DatasetKind("synthetic", replica.ReplicaDataset, None, same_layout_as="replica"),
    DatasetKind("tum", tum.TUMDataset, tum.looks_like, "TUM rgb.txt/depth.txt/groundtruth.txt",
                reference_options={"crop_size": (384, 512), "crop_edge": 8}, download="fetch"),
    DatasetKind("scannet", scannet.ScanNetDataset, scannet.looks_like, "ScanNet color/ depth/ pose/",
                reference_options={"crop_edge": 10}, download="request"),
    DatasetKind("7scenes", sevenscenes.SevenScenesDataset, sevenscenes.looks_like,
                "7-Scenes frame-NNNNNN.color.png/.depth.png/.pose.txt", download="fetch",
                hint=sevenscenes.scene_folder_hint),
    DatasetKind("bag", bag.BagDataset, bag.looks_like, "a ROS bag (a ROS 1 .bag file, or a ROS 2 folder of "
                "metadata.yaml and .db3/.mcap files)", container=True),
)}

#: loader options that reproduce the reference (ESLAM) configs' image processing, per dataset that has them
REFERENCE_OPTIONS = {name: dict(d.reference_options) for name, d in DATASETS.items()
                     if d.reference_options is not None}


def container_kind(path) -> str | None:
    """The name of the container format (:attr:`DatasetKind.container`) ``path`` holds, None for anything else."""
    p = Path(path).expanduser()
    if not p.exists():
        return None
    return next((d.name for d in DATASETS.values() if d.container and d.looks_like(p)), None)


def dataset_kind(name: str) -> DatasetKind:
    """The entry of ``name``; SlamInputError listing the choices for an unknown one."""
    if name not in DATASETS:
        raise SlamInputError(f"unknown dataset kind {name!r}; expected auto, {', '.join(DATASETS)}")
    return DATASETS[name]
