"""The scene of docs/nerf.md's nerfstudio comparisons, shared by the benchmarks that train on it
(``nerf_end_to_end.py``, and the retired ``nerf_step_split.py``) so that they measure the same room: the synthetic room exported as
a nerfstudio dataset, 24 views of 48x64 (21 for training, every 8th held out)."""

from __future__ import annotations

from pathlib import Path


def ensure_room(folder: Path) -> Path:
    """``folder`` holding the room as a nerfstudio dataset (``transforms.json``), written if it is not there."""
    from slam.data.synthetic import SynthConfig
    from slam.data.synthetic.nerfstudio_export import export_nerfstudio

    folder = Path(folder)
    if not (folder / "transforms.json").is_file():
        export_nerfstudio(folder, SynthConfig(frames=24, height=48, width=64, loop_frames=96))
    return folder
