"""Typed SLAM configuration: YAML presets layered base <- representation <- dataset <- scene, plus ``key=value``
overrides.

A preset is a name under ``slam/configs`` (``synthetic``, ``replica/room0``, ``tum/fr1_rpy-cpu`` ...) or a path
to a YAML file. Layering: ``base.yaml`` <- representation block <- the preset's parents <- the preset <- overrides.
A file's parent is its ``inherit`` key when present, else the folder's dataset file (``tum/x`` inherits ``tum``),
else ``base``. The ``representation`` key (``lrslam`` default, ``eslam``, ``cp_cp``, ``sa_sa``, ``sa_cp``,
``vm_sa``) picks ``configs/representations/<name>.yaml``, which sets each quantity's field kind and rank; cell
sizes and channels come from ``base.yaml`` (the same grids for every representation), and any explicit key (a
preset's or an override's) wins.

Every key is checked against the dataclasses below, and every numeric key against its range (``num(...)``): an
unknown key or file, a badly typed or out-of-range value raises :class:`slam.errors.SlamInputError` naming the key,
the value and what is allowed. Defaults are ESLAM's (eslam-pipeline.md) unless a field's comment says otherwise.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union, get_args, get_origin, get_type_hints

import yaml

from slam.errors import SlamInputError
from slam.losses import LossWeights

CONFIG_DIR = Path(__file__).parent / "configs"
REPRESENTATIONS = ("lrslam", "eslam", "cp_cp", "sa_sa", "sa_cp", "vm_sa")
FIELD_KINDS = ("cp", "dense_grid", "six_axis", "triplane", "vector_matrix")  # tdfields.KINDS


# --------------------------------------------------------------------------------------------------- ranges
@dataclass(frozen=True)
class Range:
    """The allowed values of a numeric key: ``lo``/``hi`` bounds (None: unbounded), each closed unless
    ``*_open``. Lists are checked element by element; ``None`` passes where the key is optional."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def ok(self, v: float) -> bool:
        if v != v:  # NaN
            return False
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        if self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi):
            return False
        return True

    def __str__(self) -> str:
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}")
        return " and ".join(parts) or "any number"


def num(default, lo=None, hi=None, lo_open=False, hi_open=False, **kw):
    """A dataclass field with a numeric range (see :class:`Range`), checked by :func:`load_config`."""
    meta = {"range": Range(lo, hi, lo_open, hi_open)}
    if callable(default):
        return field(default_factory=default, metadata=meta, **kw)
    return field(default=default, metadata=meta, **kw)


def choice(default, options: tuple, **kw):
    """A dataclass field whose value must be one of ``options``."""
    return field(default=default, metadata={"choices": tuple(options)}, **kw)


COUNT = {"lo": 1}          # iteration and pixel counts, sizes
POSITIVE = {"lo": 0, "lo_open": True}   # lengths, learning rates, scales
NONNEG = {"lo": 0}         # weights, margins
FRACTION = {"lo": 0, "hi": 1}


@dataclass
class DataConfig:
    """Dataset: ``kind`` is passed to ``slam.data.load_dataset`` (``auto``, ``replica``, ``tum``, ``scannet``...);
    ``path`` null means the bundled synthetic sequence. ``options`` are loader options (crop_edge, crop_size,
    undistort, ...). ``max_frames`` and ``stride`` subsample the sequence. A frame that cannot be read (missing,
    truncated, wrong size) is skipped and listed in ``events``; once more than ``max_bad_fraction`` of the
    sequence's frames were bad, the run stops with an error (after its outputs are written)."""

    kind: str = "auto"
    path: Optional[str] = None
    max_frames: Optional[int] = num(None, **COUNT)
    stride: int = num(1, **COUNT)
    max_bad_fraction: float = num(0.1, **FRACTION)
    prefetch: int = num(2, **NONNEG)  # frames read ahead on a background thread (0: on demand)
    options: dict = field(default_factory=dict)


@dataclass
class FieldSpec:
    """One quantity's field: ``kind`` (tdfields kind), ``cell_sizes`` per level (coarse, fine) in metres,
    ``rank`` (cp / six_axis / vector_matrix), ``channels`` per level, ``init_std``."""

    kind: str = choice("cp", FIELD_KINDS)
    cell_sizes: list = num(lambda: [0.24, 0.06], **POSITIVE)
    rank: int = num(2, **COUNT)
    channels: int = num(32, **COUNT)
    init_std: Optional[float] = num(None, **POSITIVE)  # null: the kind's tdfields default


@dataclass
class SceneConfig:
    """Scene box and SDF model. ``bound``: ``[[x0,x1],[y0,y1],[z0,z1]]`` or ``auto`` (from the first frames'
    depth, see ``bound_auto_*``). ``marching_cubes_bound``: null = the bound."""

    bound: Any = "auto"
    marching_cubes_bound: Any = None
    bound_dividable: float = num(0.24, **POSITIVE)
    bound_auto_frames: int = num(10, **COUNT)
    bound_auto_margin: float = num(1.0, **NONNEG)
    bound_auto_percentile: float = num(99.0, lo=0, hi=100, lo_open=True)
    truncation: float = num(0.06, **POSITIVE)
    learnable_beta: bool = True
    beta_init: float = num(10.0, **POSITIVE)
    decoder_hidden: int = num(16, **COUNT)


def _weights(fs, center, tail, depth, color):
    return lambda: LossWeights(fs=fs, center=center, tail=tail, depth=depth, color=color)


# the one definition of ESLAM's loss weights (eslam-pipeline.md §3); LossWeights itself lives with the losses
TRACKING_WEIGHTS = _weights(10.0, 200.0, 50.0, 1.0, 5.0)
MAPPING_WEIGHTS = _weights(5.0, 200.0, 10.0, 0.1, 5.0)


@dataclass
class RenderingConfig:
    """Samples per ray (``n_stratified`` in [0, 1.2 D] + ``n_importance`` in D +- 1.5 T), jitter, and
    ``color_cutoff``: samples whose compositing weight is at most this skip the colour query (0: every sample,
    as ESLAM)."""

    n_stratified: int = num(32, lo=2)
    n_importance: int = num(8, **NONNEG)
    perturb: bool = True
    color_cutoff: float = num(0.0, lo=0, hi=1, hi_open=True)


@dataclass
class TrackingConfig:
    iters: int = num(8, **COUNT)
    pixels: int = num(2000, lo=10)
    lr_t: float = num(0.001, **POSITIVE)
    lr_r: float = num(0.001, **POSITIVE)
    ignore_edge: list = num(lambda: [75, 75], **NONNEG)
    # the starting pose: ESLAM's constant velocity (const_speed), the previous pose, or depth ICP from the
    # previous frame started at the constant-velocity guess (ours; slam/odometry.py)
    init: str = choice("const_speed", ("const_speed", "previous", "icp"))
    outlier_factor: float = num(10.0, **POSITIVE)
    # ours: stop once `patience` iterations found no loss below the best by `min_improvement` (0: ESLAM's fixed count)
    patience: int = num(0, **NONNEG)
    min_iters: int = num(1, **COUNT)
    min_improvement: float = num(0.0, lo=0, hi=1, hi_open=True)
    # ours (slam/tracking_guard.py): a result is implausible when its loss is over lost_loss_factor x the recent
    # median, fewer than lost_min_inliers of its rays are inliers, or it moved faster than max_speed (m/s) /
    # max_angular_speed (deg/s); then `recovery` tracks again from several starts. 0 turns a check off.
    lost_loss_factor: float = num(4.0, **NONNEG)
    lost_min_inliers: float = num(0.5, **FRACTION)
    max_speed: float = num(3.0, **NONNEG)
    max_angular_speed: float = num(360.0, **NONNEG)
    recovery: bool = True
    weights: LossWeights = field(default_factory=TRACKING_WEIGHTS)


@dataclass
class MappingConfig:
    every_frame: int = num(4, **COUNT)
    keyframe_every: int = num(4, **COUNT)
    iters: int = num(15, **COUNT)
    iters_first: int = num(1000, **COUNT)
    lr_first_factor: float = num(5.0, **POSITIVE)
    pixels: int = num(4000, **COUNT)
    lr_decoders: float = num(0.001, **POSITIVE)
    lr_geometry: float = num(0.005, **POSITIVE)
    lr_appearance: float = num(0.005, **POSITIVE)
    window_size: int = num(20, **COUNT)
    keyframe_selection: str = choice("overlap", ("overlap", "global"))
    overlap_pixels: int = num(50, **COUNT)
    overlap_samples: int = num(8, lo=2)
    joint_opt: bool = True
    joint_opt_cam_lr: float = num(0.001, **POSITIVE)
    ba_min_keyframes: int = num(4, **NONNEG)
    # ours: keyframe images as loaded (float32) or 8-bit colour + float16 depth (compact, 3.2x less memory)
    keyframe_storage: str = choice("float32", ("float32", "compact"))
    max_keyframes: int = num(0, **NONNEG)  # ours: 0 keeps all; else the most redundant one goes (bounded memory)
    weights: LossWeights = field(default_factory=MAPPING_WEIGHTS)


@dataclass
class MeshingConfig:
    """Mesh extraction: grid ``resolution`` (metres), points per SDF ``batch``, the visibility hull and culling."""

    resolution: float = num(0.01, **POSITIVE)
    batch: int = num(500000, **COUNT)
    hull_scale: float = num(1.02, **POSITIVE)
    hull_points_per_frame: int = num(2000, **COUNT)
    cull: bool = True
    cull_depth_test: bool = True


@dataclass
class EvaluationConfig:
    """Reconstruction metrics against a ground-truth mesh: points sampled per mesh, ICP alignment first, and the
    number of random views of Depth L1 (0: skip it)."""

    samples: int = num(200000, **COUNT)
    icp: bool = True
    depth_l1_views: int = num(1000, **NONNEG)


@dataclass
class Config:
    """The resolved configuration (written as ``config.yaml`` next to a run's outputs)."""

    name: str = "custom"
    seed: int = num(0, **NONNEG)
    device: str = "cpu"
    threads: int = num(0, **NONNEG)  # 0 = leave torch's default
    keep_freed_memory: bool = True  # glibc: reuse freed big tensors instead of fresh pages (slam.runtime)
    parallel: bool = False  # mapping on a worker thread beside the tracker (slam.map_worker)
    checkpoint_every: int = num(0, **NONNEG)  # frames between checkpoints (0: by time, checkpoint_interval_s)
    checkpoint_interval_s: float = num(60.0, **POSITIVE)  # at most this much work is lost (checkpoint_every: 0)
    representation: str = choice("lrslam", REPRESENTATIONS)
    data: DataConfig = field(default_factory=DataConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    geometry: FieldSpec = field(default_factory=FieldSpec)
    appearance: FieldSpec = field(
        default_factory=lambda: FieldSpec(kind="six_axis", cell_sizes=[0.24, 0.03], rank=16, channels=32)
    )
    rendering: RenderingConfig = field(default_factory=RenderingConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    meshing: MeshingConfig = field(default_factory=MeshingConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------------------------------- merging
def _deep_merge(base: dict, update: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and k != "options":
            out[k] = _deep_merge(out[k], v)
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = copy.deepcopy(v)
    return out


def _read_yaml(path: Path, what: str) -> dict:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SlamInputError(f"{what} not found: {path}") from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise SlamInputError(f"{path}: invalid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise SlamInputError(f"{path}: a config file must be a mapping of keys, got {type(data).__name__}")
    return data


def list_presets() -> list[str]:
    """Names of the bundled presets (dataset files and scene files, not base or representation blocks)."""
    names = []
    for p in sorted(CONFIG_DIR.rglob("*.yaml")):
        rel = p.relative_to(CONFIG_DIR).with_suffix("").as_posix()
        if rel == "base" or rel.startswith("representations/"):
            continue
        names.append(rel)
    return names


def _preset_path(name: str) -> Path:
    p = Path(name)
    if p.suffix in (".yaml", ".yml"):
        if not p.is_file():
            raise SlamInputError(f"config file not found: {name}")
        return p
    cand = CONFIG_DIR / f"{name}.yaml"
    if not cand.is_file():
        raise SlamInputError(f"unknown preset '{name}'; available: {', '.join(list_presets())} (or a .yaml path)")
    return cand


def _preset_chain(name: str, seen: tuple = ()) -> list[dict]:
    """Layers for a preset, parents first (base excluded)."""
    if name in seen:
        raise SlamInputError(f"preset inheritance cycle: {' -> '.join(seen + (name,))}")
    path = _preset_path(name)
    data = _read_yaml(path, "config file")
    parent = data.pop("inherit", None)
    if parent is None and "/" in name and not name.endswith((".yaml", ".yml")):
        parent = name.split("/", 1)[0]
    chain = _preset_chain(parent, seen + (name,)) if parent not in (None, "base") else []
    return chain + [data]


def parse_overrides(items: list[str] | None) -> dict:
    """``["a.b=1", "c=[1,2]"]`` -> nested dict; values parsed as YAML scalars/lists."""
    out: dict = {}
    for item in items or []:
        if "=" not in item:
            raise SlamInputError(f"override '{item}' must look like key=value (e.g. tracking.iters=10)")
        key, value = item.split("=", 1)
        key = key.strip()
        if not key:
            raise SlamInputError(f"override '{item}' has an empty key")
        try:
            parsed = yaml.safe_load(value) if value.strip() else None
        except yaml.YAMLError:
            parsed = value
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise SlamInputError(f"override '{item}' conflicts with another override")
        node[parts[-1]] = parsed
    return out


# --------------------------------------------------------------------------------------------------- typing
# YAML 1.1 (PyYAML) reads exponent notation without a dot, "1e-3", as a string
_EXPONENT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = get_origin(tp)
    if origin is Union:
        args = [a for a in get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _coerce(value, args[0], key)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise SlamInputError(f"config key '{key}' must be a mapping, got {value!r}")
        return _build(tp, value, key + ".")
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise SlamInputError(f"config key '{key}' must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or int(value) != value:
            raise SlamInputError(f"config key '{key}' must be an integer, got {value!r}")
        return int(value)
    if tp is float:
        # YAML 1.1 reads exponent notation without a dot ("1e-3") as a string; accept it as the number it spells
        if isinstance(value, str) and _EXPONENT.fullmatch(value.strip()):
            return float(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SlamInputError(f"config key '{key}' must be a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise SlamInputError(f"config key '{key}' must be a string, got {value!r}")
        return str(value)
    if tp is list or origin is list:
        if not isinstance(value, (list, tuple)):
            raise SlamInputError(f"config key '{key}' must be a list, got {value!r}")
        return list(value)
    if tp is dict or origin is dict:
        if not isinstance(value, dict):
            raise SlamInputError(f"config key '{key}' must be a mapping, got {value!r}")
        return dict(value)
    return value


# keys that moved: old dotted key -> new dotted key (a clear error instead of "unknown key")
MOVED = {
    "meshing.eval_samples": "evaluation.samples",
    "meshing.eval_icp": "evaluation.icp",
    "meshing.depth_l1_views": "evaluation.depth_l1_views",
    "tracking.const_speed": "tracking.init (const_speed, previous or icp)",
}


# classes defined outside this module whose every field shares one range
_CLASS_RANGES = {LossWeights: Range(**NONNEG)}


def _check_value(key: str, value: Any, meta, default_range: Range | None = None) -> None:
    rng: Range | None = meta.get("range", default_range)
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise SlamInputError(f"config key '{key}' = {value!r} is not allowed; choose from {', '.join(map(str, choices))}")
    if rng is None or value is None:
        return
    for v in value if isinstance(value, list) else [value]:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SlamInputError(f"config key '{key}' must hold numbers, got {value!r}")
        if not rng.ok(float(v)):
            raise SlamInputError(f"config key '{key}' = {value!r} is out of range: must be {rng}")


def _build(cls, data: dict, prefix: str = ""):
    hints = get_type_hints(cls)
    fields_ = {f.name: f for f in dataclasses.fields(cls)}
    for k in data:
        if k not in fields_:
            moved = MOVED.get(prefix + k)
            if moved:
                raise SlamInputError(f"config key '{prefix}{k}' is now '{moved}'")
            raise SlamInputError(f"unknown config key '{prefix}{k}'; valid keys here: {', '.join(sorted(fields_))}")
    kwargs = {}
    for k, v in data.items():
        f = fields_[k]
        if isinstance(v, dict) and dataclasses.is_dataclass(hints[k]) and f.default_factory is not dataclasses.MISSING:
            # a partial mapping fills in from this field's own default (mapping.weights is not tracking.weights)
            v = {**dataclasses.asdict(f.default_factory()), **v}
        kwargs[k] = _coerce(v, hints[k], prefix + k)
        _check_value(prefix + k, kwargs[k], fields_[k].metadata, _CLASS_RANGES.get(cls))
    return cls(**kwargs)


def _upgraded(data: dict) -> dict:
    """``data`` with every key of :data:`MOVED` put where it lives now (configs written by older versions)."""
    out = copy.deepcopy(data)
    tracking = out.get("tracking")
    if isinstance(tracking, dict) and "const_speed" in tracking:
        tracking.setdefault("init", "const_speed" if tracking.pop("const_speed") else "previous")
    for old, new in MOVED.items():
        *path, leaf = old.split(".")
        node = out
        for part in path:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict) and leaf in node:
            value = node.pop(leaf)
            *npath, nleaf = new.split(".")
            target = out
            for part in npath:
                target = target.setdefault(part, {})
            target.setdefault(nleaf, value)
    return out


def config_from_dict(data: dict, upgrade: bool = False) -> Config:
    """A validated :class:`Config` from a plain dict (e.g. ``config.yaml`` of a run or a checkpoint's config).

    Args:
        upgrade: first move keys that older versions wrote elsewhere (:data:`MOVED`); for configs this library
            wrote itself (checkpoints, run folders), not for a user's YAML, which gets the error naming the new key.

    Raises:
        SlamInputError: an unknown key, a badly typed or out-of-range value.
    """
    if not isinstance(data, dict):
        raise SlamInputError(f"a config must be a mapping of keys, got {type(data).__name__}")
    if upgrade:
        data = _upgraded(data)
    cfg = _build(Config, data)
    _validate(cfg)
    return cfg


def _validate(cfg: Config) -> None:
    """Checks across keys (each key's own range is checked as it is read)."""
    if cfg.device not in ("cpu", "cuda") and not cfg.device.startswith("cuda:"):
        raise SlamInputError(f"device must be cpu or cuda, got '{cfg.device}'")
    for label, spec in (("geometry", cfg.geometry), ("appearance", cfg.appearance)):
        if not spec.cell_sizes:
            raise SlamInputError(f"config key '{label}.cell_sizes' must be a non-empty list of positive metres")
    for key in ("bound", "marching_cubes_bound"):
        b = getattr(cfg.scene, key)
        if b is None and key == "marching_cubes_bound" or b == "auto" and key == "bound":
            continue
        ok = isinstance(b, list) and len(b) == 3 and all(
            isinstance(r, list) and len(r) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                        for v in r) and r[0] < r[1] for r in b)
        if not ok:
            allowed = "'auto' or " if key == "bound" else "null or "
            raise SlamInputError(f"config key 'scene.{key}' must be {allowed}[[x0,x1],[y0,y1],[z0,z1]] with "
                                 f"x0 < x1 (metres), got {b!r}")
    if len(cfg.tracking.ignore_edge) != 2:
        raise SlamInputError(f"config key 'tracking.ignore_edge' must be [rows, columns], got {cfg.tracking.ignore_edge!r}")


def _representation(layers: list[dict]) -> str:
    rep = "lrslam"
    for layer in layers:
        rep = layer.get("representation", rep)
    if rep not in REPRESENTATIONS:
        raise SlamInputError(f"unknown representation '{rep}'; choose from {', '.join(REPRESENTATIONS)}")
    return rep


def _alias(over: dict) -> dict:
    """Short override aliases: ``bound=auto`` means ``scene.bound``."""
    over = dict(over)
    if "bound" in over:
        over.setdefault("scene", {})
        over["scene"] = {**over["scene"], "bound": over.pop("bound")}
    return over


def load_config(preset: str | None = "synthetic", overrides: list[str] | dict | None = None) -> Config:
    """Resolve a preset (name or YAML path) plus overrides into a validated :class:`Config`.

    Layers, each overriding the one before: ``base.yaml``, the representation block the layers name
    (``representations/<name>.yaml``), the preset's parents, the preset, the overrides.

    Raises:
        SlamInputError: unknown preset, file, key, representation, or a badly typed / out-of-range value.
    """
    preset = preset or "synthetic"
    base = _read_yaml(CONFIG_DIR / "base.yaml", "base config")
    over = overrides if isinstance(overrides, dict) else parse_overrides(overrides)
    layers = _preset_chain(preset) + [_alias(over)]
    rep = _representation([base] + layers)
    merged = _deep_merge(base, _read_yaml(CONFIG_DIR / "representations" / f"{rep}.yaml", "representation block"))
    for layer in layers:
        merged = _deep_merge(merged, layer)
    if "name" not in over:
        merged["name"] = Path(preset).stem if preset.endswith((".yaml", ".yml")) else preset
    return config_from_dict(merged)


def save_config(cfg: Config, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
