"""The ``data`` section: which sequence a run reads, and how its frames are read."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from slam.config.declare import COUNT, FRACTION, choice, key, num


@dataclass
class DataConfig:
    """The sequence and how its frames are read. ``kind`` is not a schema choice: slam.config sits below slam.data,
    whose registry holds the kinds (a test checks the presets' kinds); ``options`` are checked against the kind's
    loader by slam.engine.setup.check_data_options, where a run starts."""

    kind: str = key("auto", "dataset kind given to `slam.data.load_dataset`: `auto` (detected from the folder) or a "
                            "name in `slam.data.DATASETS` (`replica`, `tum`, `scannet`, `7scenes`, `bag`, `synthetic`...)")
    path: Optional[str] = key(None, "dataset folder, ROS 1 `.bag` file or ROS 2 bag folder (`--data` sets it); null: "
                                    "the bundled synthetic sequence")
    max_frames: Optional[int] = num(None, **COUNT, doc="at most this many of the selected frames; null: all")
    stride: int = num(1, **COUNT, doc="every `stride`-th frame of the sequence is selected")
    max_bad_fraction: float = num(0.1, **FRACTION, doc=(
        "(ours) a frame that cannot be read (missing, truncated, wrong size) is skipped and listed in the events; "
        "once more than this share of the sequence's frames were bad the run stops with an error, its outputs "
        "written"))
    prefetch: int = num(2, lo=0, hi=64, doc="(ours) frames read ahead of the tracker (0: on demand; a `realtime` "
                                            "run reads on demand)")
    prefetch_in: str = choice("thread", ("thread", "waits"), doc=(
        "(ours) read ahead on a background `thread`, or in the tracker's `waits` for the mapper (no thread beside "
        "the tracker; the same frames; slam/engine/frames.py)"))
    realtime: bool = key(False, "(ours) replay the frames at their recorded rate as a live camera delivers them: the "
                                "newest frame that has arrived is processed next, the ones it passed are dropped "
                                "(`--realtime` sets it; slam/engine/realtime.py)")
    options: dict = key(dict, "the kind's loader options (`crop_edge_raw`, `crop_size`, `undistort`, `focal_px`, "
                              "...); a synthetic kind's with `path` null also `scene` and the generator's (`seed`, "
                              "`frames`, `height`, ...: SynthConfig's fields)", type_name="mapping")
