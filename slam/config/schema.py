"""The configuration's schema: every key of a SLAM run as a typed dataclass field, with its default and its range.

``num(default, lo=..., hi=...)`` declares a numeric key's allowed values, ``choice(default, options)`` an
enumerated one; :mod:`slam.config.validate` checks every value against them as a config is read. Defaults are ESLAM's
(docs/slam.md, "The pipeline (as implemented)") unless a field's comment says "ours".
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Optional

import tdfields
from slam.config.declare import (BIG, COUNT, FRACTION, METRES, NONNEG, POSITIVE, RATE, Range, RegistryNames, choice,
                                 num)
from slam.config.presets import CONFIG_DIR
from slam.core.losses import LossWeights

# the declaration helpers are importable from here too (they were defined here)
__all__ = ["BIG", "COUNT", "FRACTION", "FIELD_KINDS", "KEYFRAME_STORAGES", "METRES", "NONNEG", "POSITIVE", "RATE",
           "REPRESENTATIONS", "Range", "RegistryNames", "choice", "num"]


#: the representation blocks, one per ``slam/configs/representations/<name>.yaml``: the default first, then sorted
REPRESENTATIONS = ("lrslam", *sorted(p.stem for p in (CONFIG_DIR / "representations").glob("*.yaml")
                                     if p.stem != "lrslam"))
#: the field kinds of ``geometry.kind`` / ``appearance.kind``: :data:`tdfields.KINDS`, as registered when read
FIELD_KINDS = RegistryNames(tdfields.KINDS)
#: ``mapping.keyframe_storage``: images as loaded, or 8-bit colour + float16 depth (slam.engine.keyframes)
KEYFRAME_STORAGES = ("float32", "compact")


@dataclass
class DataConfig:
    """Dataset: ``kind`` is passed to ``slam.data.load_dataset`` (``auto`` or a name in ``slam.data.DATASETS``:
    ``replica``, ``tum``, ``scannet``...; not a schema choice, as slam.config sits below slam.data: a test checks
    the presets' kinds); ``path`` null means the bundled synthetic sequence. ``options`` are loader options
    (crop_edge, crop_size, undistort, ...: those of the kind's loader, checked by
    slam.engine.setup.check_data_options); a synthetic kind's with ``path`` null also ``scene`` and the
    generator's (seed, frames, height, ...: SynthConfig's fields). ``max_frames`` and ``stride`` subsample the
    sequence. A frame that cannot be read (missing, truncated, wrong size) is skipped and listed in ``events``;
    once more than ``max_bad_fraction`` of the sequence's frames were bad, the run stops with an error (after its outputs are written)."""

    kind: str = "auto"
    path: Optional[str] = None
    max_frames: Optional[int] = num(None, **COUNT)
    stride: int = num(1, **COUNT)
    max_bad_fraction: float = num(0.1, **FRACTION)
    prefetch: int = num(2, lo=0, hi=64)  # frames read ahead (0: on demand)
    # ours (slam/engine/frames.py): read them on a background thread, or in the tracker's waits for the mapper
    # (waits: no thread beside the tracker; the same frames)
    prefetch_in: str = choice("thread", ("thread", "waits"))
    # ours (slam/engine/realtime.py): replay the frames at their recorded rate as a live camera delivers them; the
    # newest frame that has arrived is processed next, the ones it passed are dropped (frames are then read on demand)
    realtime: bool = False
    options: dict = field(default_factory=dict)


@dataclass
class FieldSpec:
    """One quantity's field: ``kind`` (tdfields kind), ``cell_sizes`` per level (coarse, fine) in metres,
    ``rank`` (cp / six_axis / vector_matrix), ``channels`` per level, ``init_std``."""

    kind: str = choice("cp", FIELD_KINDS)
    cell_sizes: list = num(lambda: [0.24, 0.06], **METRES)
    rank: int = num(2, lo=1, hi=4096)
    channels: int = num(32, lo=1, hi=4096)
    init_std: Optional[float] = num(None, **POSITIVE)  # null: the kind's tdfields default


@dataclass
class SceneConfig:
    """Scene box and SDF model. ``bound``: ``[[x0,x1],[y0,y1],[z0,z1]]`` or ``auto`` (from the first frames'
    depth, see ``bound_auto_*``). ``marching_cubes_bound``: null = the bound. ``grow*``: a box that grows (ours,
    slam.engine.growth_policy; ``grow: auto`` grows an ``auto`` bound and keeps a given one; true / false: always,
    never)."""

    bound: Any = "auto"
    marching_cubes_bound: Any = None
    bound_dividable: float = num(0.24, **METRES)
    bound_auto_frames: int = num(10, **COUNT)
    bound_auto_margin: float = num(1.0, lo=0, hi=1000.0)
    bound_auto_percentile: float = num(99.0, lo=0, hi=100, lo_open=True)
    grow: Any = choice("auto", ("auto", True, False))
    grow_margin: float = num(0.3, lo=0, hi=1000.0)  # metres between a frame's depth and the box that grow it
    grow_max_extent: float = num(20.0, **METRES)  # metres per axis the box never grows past (an event says so)
    # ours: which depth grows the box. depth: every reading; box: only readings within the automatic box's radius
    # (its half-size at the start) of the camera, so a camera turning in place, whose far walls the first frames'
    # box left out on purpose, does not grow it, and one that moves does (a given box: every reading)
    grow_reach: str = choice("depth", ("depth", "box"))
    truncation: float = num(0.06, **METRES)
    learnable_beta: bool = True
    beta_init: float = num(10.0, **POSITIVE)
    decoder_hidden: int = num(16, lo=1, hi=4096)


def _weights(**weights: float):
    return lambda: LossWeights(**weights)


# the one definition of ESLAM's loss weights (docs/slam.md, Losses); LossWeights itself lives with the losses, one
# weight per term of slam.core.losses.LOSS_TERMS (a term left out here takes its LossWeights default)
TRACKING_WEIGHTS = _weights(fs=10.0, center=200.0, tail=50.0, depth=1.0, color=5.0)
MAPPING_WEIGHTS = _weights(fs=5.0, center=200.0, tail=10.0, depth=0.1, color=5.0)


@dataclass
class RenderingConfig:
    """Samples per ray (``n_stratified`` in [0, 1.2 D] + ``n_importance`` in D +- 1.5 T), jitter, and
    ``color_cutoff``: samples whose compositing weight is at most this skip the colour query (0: every sample,
    as ESLAM)."""

    n_stratified: int = num(32, lo=2, hi=4096)
    n_importance: int = num(8, lo=0, hi=4096)
    perturb: bool = True
    color_cutoff: float = num(0.0, lo=0, hi=1, hi_open=True)
    # ours (slam/core/fused_render.py): compositing, the colour sum and the five loss terms as numba kernels on the
    # CPU, Triton kernels on CUDA with TDFIELDS_BACKEND=triton (the PyTorch ops otherwise, and with
    # TDFIELDS_BACKEND=torch); same values to a few ulp. Off: 2-6 % off a call alone, no measurable change of the
    # loop's frame time at the Adam preset (docs/benchmarks.md, "The fused render tail"); on in tum/fr1_rpy-cpu-fast
    fused: bool = False


@dataclass
class TrackingConfig:
    iters: int = num(8, **COUNT)
    pixels: int = num(2000, lo=10, hi=BIG)
    lr_t: float = num(0.001, **RATE)
    lr_r: float = num(0.001, **RATE)
    ignore_edge: list = num(lambda: [75, 75], **NONNEG)
    # the starting pose: ESLAM's constant velocity (const_speed), the previous pose, or depth ICP from the
    # previous frame started at the constant-velocity guess (ours; slam/core/odometry.py)
    init: str = choice("const_speed", ("const_speed", "previous", "icp"))
    # ours (slam/core/odometry.py, hold_unobserved): with init icp, the start keeps the previous pose, not the
    # constant-velocity prediction, in the directions the depth does not observe (a single plane in view): those
    # whose point-to-plane eigenvalue is below icp_hold times the largest (0: off)
    icp_hold: float = num(3e-4, lo=0, hi=1.0)
    outlier_factor: float = num(10.0, **POSITIVE)
    # ours: stop once `patience` iterations found no loss below the best by `min_improvement` (0: ESLAM's fixed count)
    patience: int = num(0, **NONNEG)
    min_iters: int = num(1, **COUNT)
    min_improvement: float = num(0.0, lo=0, hi=1, hi_open=True)
    # ours (slam/engine/tracking_guard.py): a result is implausible when its loss is over lost_loss_factor x the recent
    # median, fewer than lost_min_inliers of its rays are inliers, or it moved faster than max_speed (m/s) /
    # max_angular_speed (deg/s); then `recovery` tracks again from several starts. 0 turns a check off.
    lost_loss_factor: float = num(4.0, **NONNEG)
    lost_min_inliers: float = num(0.5, **FRACTION)
    max_speed: float = num(3.0, lo=0, hi=1000.0)
    max_angular_speed: float = num(360.0, lo=0, hi=100000.0)
    recovery: bool = True
    # ours (slam/engine/recovery.py): after this many frames in a row without a trusted pose (lost, unreadable or
    # without depth), relocalise against the relocalize_keyframes keyframes nearest the last trusted pose
    # (0: never)
    relocalize_after: int = num(5, lo=0, hi=BIG)
    relocalize_keyframes: int = num(3, lo=1, hi=100)
    # ours (slam/engine/tracker.py, track_on_color): a frame without valid depth is tracked on its colour against
    # the map's rendered depth (color), or keeps the motion model's prediction (predict, as before); either way it
    # is not mapped
    without_depth: str = choice("color", ("color", "predict"))
    weights: LossWeights = field(default_factory=TRACKING_WEIGHTS)
    # ours (slam/engine/gauss_newton.py): adam is ESLAM's tracker (iters, lr_r, lr_t, patience apply); gauss_newton
    # solves the pose by Levenberg-Marquardt on one set of pixels: at most gn_iters loss evaluations, the damping
    # starting at gn_damping, converged once a step moves the camera less than gn_step_m and gn_step_deg
    optimizer: str = choice("adam", ("adam", "gauss_newton"))
    gn_iters: int = num(10, lo=2, hi=1000)
    gn_damping: float = num(1e-3, lo=0, hi=1e6)
    gn_step_m: float = num(1e-4, lo=0, hi=1.0)
    gn_step_deg: float = num(0.01, lo=0, hi=90.0)
    # ours: later rounds draw fresh pixels and redo the outlier rule at the pose the previous round reached
    gn_rounds: int = num(1, lo=1, hi=100)
    # ours: "every" evaluation brings the full normal equations (H from one coordinate backward per residual kind);
    # "first": only a round's first, later ones the gradient alone (one backward pass) with that H kept
    gn_hessian: str = choice("every", ("every", "first"))
    # ours: a prior towards the start pose: kappa times the mean curvature of the rotation / translation axes, the
    # same on every axis of each (0: none)
    gn_prior: float = num(0.0, lo=0, hi=1e6)


@dataclass
class MappingConfig:
    every_frame: int = num(4, **COUNT)
    keyframe_every: int = num(4, **COUNT)
    iters: int = num(15, **COUNT)
    iters_first: int = num(1000, **COUNT)
    lr_first_factor: float = num(5.0, **POSITIVE)
    pixels: int = num(4000, **COUNT)
    lr_decoders: float = num(0.001, **RATE)
    lr_geometry: float = num(0.005, **RATE)
    lr_appearance: float = num(0.005, **RATE)
    # ours: "matched" scales each field factor's rate so one Adam step moves a product term's features as far as a
    # plane's (tdfields.step_scale; planes, grids unchanged); "lift": only where that raises the rate; "none": ESLAM's
    lr_scaling: str = choice("none", ("none", "matched", "lift"))
    window_size: int = num(20, **COUNT)
    keyframe_selection: str = choice("overlap", ("overlap", "global"))
    overlap_pixels: int = num(50, **COUNT)
    overlap_samples: int = num(8, lo=2, hi=4096)
    joint_opt: bool = True
    joint_opt_cam_lr: float = num(0.001, **RATE)
    ba_min_keyframes: int = num(4, **NONNEG)
    # ours: keyframe images as loaded (float32) or 8-bit colour + float16 depth (compact, 3.2x less memory)
    keyframe_storage: str = choice("float32", KEYFRAME_STORAGES)
    max_keyframes: int = num(0, **NONNEG)  # ours: 0 keeps all; else the most redundant one goes (bounded memory)
    # ours: the newest N keyframes' images stay in memory, older ones go to a temporary file in keyframe_spill_dir
    # ("": the system's) and are read back bit-identical when selected (slam.engine.keyframe_spill); 0: all in memory
    keyframes_in_memory: int = num(100, **NONNEG)
    keyframe_spill_dir: str = ""
    weights: LossWeights = field(default_factory=MAPPING_WEIGHTS)
    # ours (slam/engine/schedule.py): every_frame is ESLAM's fixed schedule; by_need maps the first need_young frames,
    # then a frame when need_max_gap frames passed since the last mapped one or its tracking loss is over
    # need_loss_factor x the recent median (every_frame then only sets the parallel mode's lag)
    schedule: str = choice("every_frame", ("every_frame", "by_need"))
    need_young: int = num(20, **NONNEG)
    need_max_gap: int = num(3, **COUNT)
    need_loss_factor: float = num(1.2, lo=1.0, hi=1000.0)
    # ours: iterations of a by_need call made only because need_max_gap frames passed (a routine refresh; the young
    # frames', the loss-triggered and the last frame's calls keep `iters`); 0: `iters`
    need_gap_iters: int = num(0, **NONNEG)
    # ours (slam/engine/mapper.py, MapMoments): per_call is ESLAM's fresh Adam every call; persistent carries the
    # map's Adam moments from call to call (as Co-SLAM's one map optimiser), the BA poses' Adam still fresh per call
    optimizer_state: str = choice("per_call", ("per_call", "persistent"))
    # ours (slam/engine/mapper.py): "render" maps the window's pixels without a depth reading too (their colour alone,
    # after a no-grad SDF pass to place their samples); "skip" maps only pixels with depth, as the tracker does
    rays_without_depth: str = choice("render", ("render", "skip"))


@dataclass
class MeshingConfig:
    """Mesh extraction: grid ``resolution`` (metres), points per SDF ``batch``, the visibility hull and culling."""

    resolution: float = num(0.01, **METRES)
    batch: int = num(500000, lo=1, hi=1_000_000_000)
    hull_scale: float = num(1.02, **POSITIVE)
    hull_points_per_frame: int = num(2000, **COUNT)
    cull: bool = True
    cull_depth_test: bool = True


@dataclass
class EvaluationConfig:
    """Reconstruction metrics against a ground-truth mesh: points sampled per mesh, ICP alignment first, and the
    number of random views of Depth L1 (0: skip it)."""

    samples: int = num(200000, lo=1, hi=1_000_000_000)
    icp: bool = True
    depth_l1_views: int = num(1000, **NONNEG)


@dataclass
class Config:
    """The resolved configuration (written as ``config.yaml`` next to a run's outputs)."""

    name: str = "custom"
    # the budget the config was read with (slam/configs/profiles/: realtime, quality, paper, or a YAML file's path);
    # a record: the profile's keys are already in the config
    profile: str = ""
    seed: int = num(0, lo=0, hi=2**32 - 1 - 7919)  # numpy seeds are 32-bit; the mapper draws from seed + 7919
    device: str = "cpu"
    threads: int = num(0, lo=0, hi=1024)  # 0 = leave torch's default
    keep_freed_memory: bool = True  # glibc: reuse freed big tensors instead of fresh pages (slam.engine.runtime)
    trim_memory_every: int = num(20, **NONNEG)  # frames between returns of the heap's free pages; 0: never
    parallel: bool = False  # mapping on a worker thread beside the tracker (slam.engine.map_worker)
    # ours: with parallel, the mapping calls run in a child process instead of a thread (slam.engine.map_process):
    # the same results; the two no longer share Python's interpreter lock
    mapper_process: bool = False
    # ours: load the fused kernels before the first frame, by a throwaway mapping and tracking call
    # (slam.engine.rehearsal); the same results, the time reported as preload_s instead of in the first frames
    preload_kernels: bool = True
    checkpoint_every: int = num(0, **NONNEG)  # frames between checkpoints (0: by time, checkpoint_interval_s)
    checkpoint_interval_s: float = num(60.0, **POSITIVE)  # at most this much work is lost (checkpoint_every: 0)
    representation: str = choice("lrslam", REPRESENTATIONS)
    data: DataConfig = field(default_factory=DataConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    geometry: FieldSpec = field(default_factory=FieldSpec)
    appearance: FieldSpec = field(default_factory=lambda: FieldSpec(kind="six_axis", cell_sizes=[0.24, 0.03], rank=16,
                                                                    channels=32))
    rendering: RenderingConfig = field(default_factory=RenderingConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    meshing: MeshingConfig = field(default_factory=MeshingConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


