"""Layout detection: ``load_dataset(path)`` picks the right loader."""

from __future__ import annotations

from pathlib import Path

from slam.errors import SlamInputError

__all__ = ["detect_layout", "load_dataset"]


def _seven_scenes_sequence(root: Path) -> bool:
    return any(root.glob("frame-*.pose.txt")) or any(root.glob("frame-*.color.*"))


def detect_layout(path) -> str:
    """``"replica"``, ``"tum"``, ``"scannet"`` or ``"7scenes"`` for a dataset folder; SlamInputError naming it
    otherwise."""
    root = Path(path)
    if not root.exists():
        raise SlamInputError(f"{root}: dataset folder not found")
    if not root.is_dir():
        raise SlamInputError(f"{root}: not a folder")
    if (root / "results").is_dir() and (root / "traj.txt").exists():
        return "replica"
    if (root / "rgb.txt").exists() or (root / "associations.txt").exists() or (root / "associate.txt").exists():
        return "tum"
    if (root / "color").is_dir() and (root / "depth").is_dir():
        return "scannet"
    if _seven_scenes_sequence(root):
        return "7scenes"
    sequences = sorted(p for p in root.glob("seq-*") if p.is_dir() and _seven_scenes_sequence(p))
    if sequences:  # a 7-Scenes scene folder holds several sequences
        raise SlamInputError(f"{root}: a 7-Scenes scene with {len(sequences)} sequences; pass one sequence folder, "
                             f"e.g. {sequences[0]}")
    raise SlamInputError(
        f"{root}: not a recognised dataset layout (expected Replica results/ + traj.txt, "
        "TUM rgb.txt/depth.txt/groundtruth.txt, ScanNet color/ depth/ pose/, or 7-Scenes "
        "frame-NNNNNN.color.png/.depth.png/.pose.txt)"
    )


def load_dataset(path, kind: str = "auto", **options):
    """Open a dataset folder.

    Args:
        path: the sequence folder.
        kind: ``"auto"`` (detect), ``"replica"`` (also the synthetic scene), ``"tum"``, ``"scannet"`` or
            ``"7scenes"``.
        **options: passed to the loader (crop_size, crop_edge, stride, max_frames, ...).
    """
    from slam.data.replica import ReplicaDataset
    from slam.data.scannet import ScanNetDataset
    from slam.data.sevenscenes import SevenScenesDataset
    from slam.data.tum import TUMDataset

    kinds = {"replica": ReplicaDataset, "synthetic": ReplicaDataset, "tum": TUMDataset, "scannet": ScanNetDataset,
             "7scenes": SevenScenesDataset}
    if kind == "auto":
        kind = detect_layout(path)
    if kind not in kinds:
        raise SlamInputError(f"unknown dataset kind {kind!r}; expected auto, {', '.join(kinds)}")
    return kinds[kind](path, **options)
