"""Layout detection: ``load_dataset(path)`` picks the right loader from :data:`slam.data.registry.DATASETS`."""

from __future__ import annotations

from pathlib import Path

from slam.data.registry import DATASETS, dataset_kind
from slam.errors import SlamInputError

__all__ = ["detect_layout", "load_dataset"]


def detect_layout(path) -> str:
    """The name of the first dataset in :data:`~slam.data.registry.DATASETS` whose probe accepts the folder
    (``"replica"``, ``"tum"``, ``"scannet"``, ``"7scenes"``, ``"bag"``...) or file (``"bag"``: a ROS 1 bag);
    SlamInputError naming it otherwise."""
    root = Path(path)
    if not root.exists():
        raise SlamInputError(f"{root}: dataset folder not found")
    probed = [d for d in DATASETS.values() if d.looks_like is not None]
    if not root.is_dir():
        # only a file format's probe (a ROS 1 bag's) can accept a file; the folder layouts' may not expect one
        for d in probed:
            if d.container and d.looks_like(root):
                return d.name
        raise SlamInputError(f"{root}: not a folder (nor a ROS 1 bag, a .bag file)")
    for d in probed:
        if d.looks_like(root):
            return d.name
    for d in probed:
        hint = d.hint(root) if d.hint is not None else None
        if hint:
            raise SlamInputError(hint)
    layouts = [d.layout for d in probed]
    raise SlamInputError(f"{root}: not a recognised dataset layout (expected {', '.join(layouts[:-1])}, "
                         f"or {layouts[-1]})")


def load_dataset(path, kind: str = "auto", **options):
    """Open a dataset folder.

    Args:
        path: the sequence folder (or ROS 1 bag file).
        kind: ``"auto"`` (detect) or a name in :data:`~slam.data.registry.DATASETS`: ``"replica"``,
            ``"synthetic"`` (a Replica folder), ``"tum"``, ``"scannet"``, ``"7scenes"``, ``"bag"``.
        **options: passed to the loader (crop_size, crop_edge, stride, max_frames, ...).
    """
    if kind == "auto":
        kind = detect_layout(path)
    return dataset_kind(kind).loader(path, **options)
