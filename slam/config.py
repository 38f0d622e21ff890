"""Typed SLAM configuration: YAML presets layered base <- dataset <- scene, plus ``key=value`` overrides.

A preset is a name under ``slam/configs`` (``synthetic``, ``replica/room0``, ``tum/fr1_rpy-cpu`` ...) or a path
to a YAML file. Layering: ``base.yaml`` <- representation block <- the preset's parents <- the preset <- overrides.
A file's parent is its ``inherit`` key when present, else the folder's dataset file (``tum/x`` inherits ``tum``),
else ``base``. The ``representation`` key (``lrslam`` default, ``eslam``, ``cp_cp``, ``sa_sa``, ``sa_cp``)
picks ``configs/representations/<name>.yaml``, which sets each quantity's field kind and rank; cell sizes and
channels come from the dataset presets, and any explicit key (a preset's or an override's) wins.

Every key is checked against the dataclasses below; an unknown key or file raises
:class:`slam.errors.SlamInputError` naming it.
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

CONFIG_DIR = Path(__file__).parent / "configs"
REPRESENTATIONS = ("lrslam", "eslam", "cp_cp", "sa_sa", "sa_cp", "vm_sa")


@dataclass
class DataConfig:
    """Dataset: ``kind`` is passed to ``slam.data.load_dataset`` (``auto``, ``replica``, ``tum``, ``scannet``...);
    ``path`` null means the bundled synthetic sequence. ``options`` are loader options (crop_edge, crop_size,
    undistort, ...). ``max_frames`` and ``stride`` subsample the sequence."""

    kind: str = "auto"
    path: Optional[str] = None
    max_frames: Optional[int] = None
    stride: int = 1
    options: dict = field(default_factory=dict)


@dataclass
class FieldSpec:
    """One quantity's field: ``kind`` (tdfields kind), ``cell_sizes`` per level (coarse, fine) in metres,
    ``rank`` (cp / six_axis / vector_matrix), ``channels`` per level, ``init_std``."""

    kind: str = "cp"
    cell_sizes: list = field(default_factory=lambda: [0.24, 0.06])
    rank: int = 2
    channels: int = 32
    init_std: Optional[float] = None  # null: the kind's tdfields default


@dataclass
class SceneConfig:
    """Scene box and SDF model. ``bound``: ``[[x0,x1],[y0,y1],[z0,z1]]`` or ``auto`` (from the first frames'
    depth, see ``bound_auto_*``). ``marching_cubes_bound``: null = the bound."""

    bound: Any = "auto"
    marching_cubes_bound: Any = None
    bound_dividable: float = 0.24
    bound_auto_frames: int = 10
    bound_auto_margin: float = 1.0
    bound_auto_percentile: float = 99.0
    truncation: float = 0.06
    learnable_beta: bool = True
    beta_init: float = 10.0
    decoder_hidden: int = 16


@dataclass
class LossWeightsConfig:
    fs: float = 10.0
    center: float = 200.0
    tail: float = 50.0
    depth: float = 1.0
    color: float = 5.0


@dataclass
class RenderingConfig:
    """Samples per ray (``n_stratified`` in [0, 1.2 D] + ``n_importance`` in D +- 1.5 T), jitter, and
    ``color_cutoff``: samples whose compositing weight is at most this skip the colour query (0: every sample,
    as ESLAM)."""

    n_stratified: int = 32
    n_importance: int = 8
    perturb: bool = True
    color_cutoff: float = 0.0


@dataclass
class TrackingConfig:
    iters: int = 8
    pixels: int = 2000
    lr_t: float = 0.001
    lr_r: float = 0.001
    ignore_edge: list = field(default_factory=lambda: [75, 75])
    const_speed: bool = True
    outlier_factor: float = 10.0
    weights: LossWeightsConfig = field(default_factory=LossWeightsConfig)


@dataclass
class MappingConfig:
    every_frame: int = 4
    keyframe_every: int = 4
    iters: int = 15
    iters_first: int = 1000
    lr_first_factor: float = 5.0
    pixels: int = 4000
    lr_decoders: float = 0.001
    lr_geometry: float = 0.005
    lr_appearance: float = 0.005
    window_size: int = 20
    keyframe_selection: str = "overlap"
    overlap_pixels: int = 50
    overlap_samples: int = 8
    joint_opt: bool = True
    joint_opt_cam_lr: float = 0.001
    ba_min_keyframes: int = 4
    weights: LossWeightsConfig = field(
        default_factory=lambda: LossWeightsConfig(fs=5.0, center=200.0, tail=10.0, depth=0.1, color=5.0)
    )


@dataclass
class MeshingConfig:
    resolution: float = 0.01
    batch: int = 500000
    hull_scale: float = 1.02
    hull_points_per_frame: int = 2000
    cull: bool = True
    cull_depth_test: bool = True
    eval_samples: int = 200000
    eval_icp: bool = True
    depth_l1_views: int = 1000


@dataclass
class Config:
    """The resolved configuration (written as ``config.yaml`` next to a run's outputs)."""

    name: str = "custom"
    seed: int = 0
    device: str = "cpu"
    threads: int = 0  # 0 = leave torch's default
    keep_freed_memory: bool = True  # glibc: reuse freed big tensors instead of fresh pages (slam.runtime)
    representation: str = "lrslam"
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


def _build(cls, data: dict, prefix: str = ""):
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in names]
    if unknown:
        raise SlamInputError(
            f"unknown config key '{prefix}{unknown[0]}'; valid keys here: {', '.join(sorted(names))}"
        )
    kwargs = {k: _coerce(v, hints[k], prefix + k) for k, v in data.items()}
    return cls(**kwargs)


def _validate(cfg: Config) -> None:
    if cfg.device not in ("cpu", "cuda") and not cfg.device.startswith("cuda:"):
        raise SlamInputError(f"device must be cpu or cuda, got '{cfg.device}'")
    for label, spec in (("geometry", cfg.geometry), ("appearance", cfg.appearance)):
        if not spec.cell_sizes or any(not (float(c) > 0) for c in spec.cell_sizes):
            raise SlamInputError(f"{label}.cell_sizes must be a non-empty list of positive metres")
        if spec.rank < 1 or spec.channels < 1:
            raise SlamInputError(f"{label}.rank and {label}.channels must be positive")
    b = cfg.scene.bound
    if b != "auto" and not (isinstance(b, list) and len(b) == 3 and all(isinstance(r, list) and len(r) == 2 for r in b)):
        raise SlamInputError(f"scene.bound must be 'auto' or [[x0,x1],[y0,y1],[z0,z1]], got {b!r}")
    if cfg.mapping.every_frame < 1 or cfg.mapping.keyframe_every < 1:
        raise SlamInputError("mapping.every_frame and mapping.keyframe_every must be >= 1")
    if cfg.mapping.keyframe_selection not in ("overlap", "global"):
        raise SlamInputError("mapping.keyframe_selection must be 'overlap' or 'global'")
    if not 0.0 <= cfg.rendering.color_cutoff < 1.0:
        raise SlamInputError(f"rendering.color_cutoff must be in [0, 1) (a compositing weight), "
                             f"got {cfg.rendering.color_cutoff}")


def _alias(over: dict) -> dict:
    """Short override aliases: ``bound=auto`` means ``scene.bound``."""
    over = dict(over)
    if "bound" in over:
        over.setdefault("scene", {})
        over["scene"] = {**over["scene"], "bound": over.pop("bound")}
    return over


def load_config(preset: str | None = "synthetic", overrides: list[str] | dict | None = None) -> Config:
    """Resolve a preset (name or YAML path) plus overrides into a validated :class:`Config`.

    Raises:
        SlamInputError: unknown preset, file, key, representation, or a badly typed value.
    """
    preset = preset or "synthetic"
    base = _read_yaml(CONFIG_DIR / "base.yaml", "base config")
    chain = _preset_chain(preset)
    over = overrides if isinstance(overrides, dict) else parse_overrides(overrides)
    over = _alias(over)
    merged = base
    for layer in chain + [over]:
        merged = _deep_merge(merged, layer)
    rep = merged.get("representation", "lrslam")
    if rep not in REPRESENTATIONS:
        raise SlamInputError(f"unknown representation '{rep}'; choose from {', '.join(REPRESENTATIONS)}")
    rep_block = _read_yaml(CONFIG_DIR / "representations" / f"{rep}.yaml", "representation block")
    merged = _deep_merge(base, rep_block)
    for layer in chain + [over]:
        merged = _deep_merge(merged, layer)
    if "name" not in over:
        merged["name"] = Path(preset).stem if preset.endswith((".yaml", ".yml")) else preset
    cfg = _build(Config, merged)
    _validate(cfg)
    return cfg


def save_config(cfg: Config, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
