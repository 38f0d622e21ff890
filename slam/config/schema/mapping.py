"""The ``mapping`` section: which frames are mapped, the keyframe window each mapping call optimises, its optimiser,
and where the keyframes are kept."""

from __future__ import annotations

from dataclasses import dataclass

from slam.config.declare import COUNT, NONNEG, POSITIVE, RATE, choice, key, num
from slam.config.schema.weights import MAPPING_WEIGHTS
from slam.core.losses import LossWeights

#: ``mapping.keyframe_storage``: images as loaded, or 8-bit colour + float16 depth (slam.engine.keyframes)
KEYFRAME_STORAGES = ("float32", "compact")

_NEED = "(ours) with `schedule: by_need`:"


@dataclass
class MappingConfig:
    """The map's optimisation: the frames mapped (ESLAM's fixed schedule, or by need: ours, slam.engine.schedule),
    the keyframe window of a call, the rates of its Adam, bundle adjustment of the window's poses, and the
    keyframe store (ours: bounded, compact or spilled to a file)."""

    every_frame: int = num(4, **COUNT, doc=(
        "map every N-th frame (ESLAM's `map_every`); with `schedule: by_need` it only sets how far the parallel "
        "tracker runs ahead: max(N, 2) frames"))
    keyframe_every: int = num(4, **COUNT, doc=(
        "a mapped frame whose position is a multiple of N is a keyframe (by_need: once N frames passed since the "
        "last keyframe)"))
    iters: int = num(15, **COUNT, doc="Adam iterations of a mapping call")
    iters_first: int = num(1000, **COUNT, doc="iterations of the first call (the fresh map's warm-up on frame 0)")
    lr_first_factor: float = num(5.0, **POSITIVE, doc="the warm-up's learning rates are this times the others")
    pixels: int = num(4000, **COUNT, doc="pixels per iteration, split evenly over the window's frames")
    lr_decoders: float = num(0.001, **RATE, doc="Adam learning rate of the decoders and beta")
    lr_geometry: float = num(0.005, **RATE, doc="Adam learning rate of the geometry field")
    lr_appearance: float = num(0.005, **RATE, doc="Adam learning rate of the appearance field")
    lr_scaling: str = choice("none", ("none", "matched", "lift"), doc=(
        "(ours) `matched` scales each field factor's rate so one Adam step moves a product term's features as far as "
        "a plane's (tdfields.step_scale; planes, grids unchanged); `lift`: only where that raises the rate; `none`: "
        "ESLAM's (the warm-up always)"))
    window_size: int = num(20, **COUNT, doc=(
        "a call optimises up to N - 1 random keyframes of the selection, the last two keyframes and the current "
        "frame (ESLAM's `mapping_window_size`)"))
    keyframe_selection: str = choice("overlap", ("overlap", "global"), doc=(
        "the window's random keyframes come from those that see the current frame's points (`overlap`, ESLAM) or "
        "from all (`global`)"))
    overlap_pixels: int = num(50, **COUNT, doc="with `overlap`: pixels of the current frame projected into the "
                                               "keyframes")
    overlap_samples: int = num(8, lo=2, hi=4096, doc="with `overlap`: points on each such pixel's ray, in "
                                                     "`[0.8 D, D + 0.5 m]`")
    joint_opt: bool = key(True, "bundle adjustment: optimise the window's poses with the map (all but the oldest and "
                                "frame 0)")
    joint_opt_cam_lr: float = num(0.001, **RATE, doc="Adam learning rate of those poses")
    ba_min_keyframes: int = num(4, **NONNEG, doc="bundle adjustment only once more than this many keyframes are "
                                                 "stored")
    keyframe_storage: str = choice("float32", KEYFRAME_STORAGES, doc=(
        "(ours) keyframe images as loaded (`float32`) or 8-bit colour + float16 depth (`compact`, 3.2x less memory)"))
    max_keyframes: int = num(0, **NONNEG, doc=(
        "(ours) 0 keeps every keyframe; N (>= 3) drops the most redundant one past N, never the first or the last "
        "two (bounded memory)"))
    keyframes_in_memory: int = num(100, **NONNEG, doc=(
        "(ours) the newest N keyframes' images stay in memory, older ones go to a temporary file and are read back "
        "bit-identical when selected (slam/engine/keyframe_spill.py); 0: all in memory"))
    keyframe_spill_dir: str = key("", "(ours) the folder of that file (\"\": the system's temporary folder); may "
                                      "change on `--resume`")
    weights: LossWeights = key(MAPPING_WEIGHTS, "the mapping loss's weight of each term (ESLAM's)")
    schedule: str = choice("every_frame", ("every_frame", "by_need"), doc=(
        "(ours) `every_frame`: ESLAM's fixed schedule; `by_need` maps the first `need_young` frames, then a frame "
        "once `need_max_gap` frames passed since the last mapped one or when its tracking loss is high "
        "(slam/engine/schedule.py)"))
    need_young: int = num(20, **NONNEG, doc=f"{_NEED} the first N frames are all mapped")
    need_max_gap: int = num(3, **COUNT, doc=f"{_NEED} a frame is mapped once N frames passed since the last mapped "
                                            "one")
    need_loss_factor: float = num(1.2, lo=1.0, hi=1000.0, doc=(
        f"{_NEED} a frame is mapped when its tracking loss is over this times the median of the recent ones"))
    need_gap_iters: int = num(0, **NONNEG, doc=(
        f"{_NEED} iterations of a call made only because `need_max_gap` frames passed (a routine refresh; the young, "
        "loss-triggered and last frames' calls keep `iters`); 0: `iters`"))
    realtime_sync: str = choice("free", ("free", "schedule"), doc=(
        "(ours) with `data.realtime` or a live camera and `parallel`: `free`: after the warm-up the tracker never waits "
        "for the mapper, it tracks on the newest map a finished call left, and a frame the schedule maps while a call "
        "is still running is not mapped (counted in `metrics.json`'s `mapping_declined`); `schedule`: the recorded "
        "run's deterministic schedule, the tracker waits for the call of frame j - max(every_frame, 2)"))
    realtime_warmup: str = choice("odometry", ("odometry", "wait"), doc=(
        "(ours) with `realtime_sync: free`: the frames that arrive while the first map is built (the warm-up call) "
        "are tracked by depth ICP against the frame before them, chained from the first frame, and not mapped "
        "(`odometry`); `wait`: the tracker waits for the warm-up and goes on from the newest frame then, a jump of "
        "as long as the warm-up took"))
    optimizer_state: str = choice("per_call", ("per_call", "persistent"), doc=(
        "(ours) `per_call`: ESLAM's fresh Adam every call; `persistent` carries the map's Adam moments from call to "
        "call (as Co-SLAM's one map optimiser), the bundle-adjusted poses' Adam still fresh per call"))
    rays_without_depth: str = choice("render", ("render", "skip"), doc=(
        "(ours) `render` maps the window's pixels without a depth reading too (their colour alone, after a no-grad "
        "SDF pass places their samples); `skip` maps only pixels with depth, as the tracker does"))
