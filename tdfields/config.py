"""Typed configs and :func:`build`: select a decomposition per quantity by configuration.

A spec is a :class:`FieldConfig` (one kind), a :class:`MultiResolutionConfig` (levels), a
:class:`HybridConfig` (named fields), or the same as a plain dict / YAML file::

    tdfields.build({"kind": "six_axis", "aabb": [[0, 4], [0, 3], [0, 2.5]], "cell_size": 0.03,
                    "channels": 32, "rank": 16})
    tdfields.build({"kind": "multires", "levels": [{"kind": "cp", ..., "cell_size": 0.24},
                                                   {"kind": "cp", ..., "cell_size": 0.06}]})

Multi-resolution shorthand: ``"cell_size": [0.24, 0.06]`` on a single-kind spec builds one level per cell size.
Unknown keys and kinds raise ``ValueError`` naming them (and the file, for YAML).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence, Union

from tdfields.cp import CP
from tdfields.dense_grid import DenseGrid
from tdfields.field import Field
from tdfields.hybrid import Hybrid
from tdfields.multires import MultiResolution
from tdfields.six_axis import SixAxis
from tdfields.triplane import TriPlane
from tdfields.vector_matrix import VectorMatrix

KINDS: dict[str, type[Field]] = {cls.kind: cls for cls in (DenseGrid, TriPlane, VectorMatrix, CP, SixAxis)}


@dataclass
class FieldConfig:
    """One field of one kind.

    Attributes:
        kind: ``dense_grid``, ``triplane``, ``vector_matrix``, ``cp`` or ``six_axis``.
        aabb: ``[[x0, x1], [y0, y1], [z0, z1]]`` metres.
        cell_size: metres between samples (exclusive with ``grid_shape``).
        grid_shape: ``(n_x, n_y, n_z)`` samples per axis.
        channels: feature width ``C``.
        rank: rank ``k`` (``vector_matrix``, ``cp``, ``six_axis`` only).
        init_std: normal init std; ``None`` takes the kind's default (0.01 for grids and planes, 0.1 for
            products of factors, whose features are products of several init draws).
        strategy: ``six_axis`` only: ``auto``, ``factors`` or ``planes`` (see :class:`tdfields.SixAxis`).
    """

    kind: str
    aabb: Sequence[Sequence[float]]
    channels: int
    cell_size: float | None = None
    grid_shape: Sequence[int] | None = None
    rank: int | None = None
    init_std: float | None = None
    strategy: str | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown field kind {self.kind!r}; choose from {sorted(KINDS)} or 'multires'/'hybrid'")
        if self.strategy is not None and self.kind != "six_axis":
            raise ValueError(f"'strategy' applies to kind six_axis only, not {self.kind!r}")


@dataclass
class MultiResolutionConfig:
    """Levels concatenated in order (coarse first by convention)."""

    levels: list[FieldConfig | "MultiResolutionConfig"] = field(default_factory=list)
    kind: str = "multires"


@dataclass
class HybridConfig:
    """Named fields, e.g. ``{"geometry": ..., "appearance": ...}``."""

    fields: dict[str, Any] = field(default_factory=dict)
    kind: str = "hybrid"


AnyConfig = Union[FieldConfig, MultiResolutionConfig, HybridConfig]


def _check_keys(d: Mapping, allowed: set[str], where: str) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def config_from_dict(d: Mapping[str, Any], where: str = "field spec") -> AnyConfig:
    """Parse and validate a plain-dict spec (as from YAML) into typed configs.

    Raises:
        ValueError: unknown keys or kinds, missing required keys; the message names the key and ``where``.
    """
    if not isinstance(d, Mapping):
        raise ValueError(f"{where}: expected a mapping, got {type(d).__name__}")
    if "kind" not in d:
        raise ValueError(f"{where}: missing key 'kind'")
    kind = d["kind"]
    if kind == "multires":
        _check_keys(d, {"kind", "levels"}, where)
        levels = d.get("levels")
        if not isinstance(levels, (list, tuple)) or not levels:
            raise ValueError(f"{where}: 'levels' must be a non-empty list of field specs")
        return MultiResolutionConfig([config_from_dict(lv, f"{where}.levels[{i}]") for i, lv in enumerate(levels)])
    if kind == "hybrid":
        _check_keys(d, {"kind", "fields"}, where)
        fields = d.get("fields")
        if not isinstance(fields, Mapping) or not fields:
            raise ValueError(f"{where}: 'fields' must be a non-empty mapping name -> spec")
        return HybridConfig({name: config_from_dict(s, f"{where}.fields.{name}") for name, s in fields.items()})
    allowed = {f.name for f in dataclasses.fields(FieldConfig)}
    _check_keys(d, allowed, where)
    for key in ("aabb", "channels"):
        if key not in d:
            raise ValueError(f"{where}: missing key {key!r}")
    if kind not in KINDS:
        raise ValueError(f"{where}: unknown field kind {kind!r}; choose from {sorted(KINDS)} or 'multires'/'hybrid'")
    cell = d.get("cell_size")
    if isinstance(cell, (list, tuple)):  # shorthand: one level per cell size
        base = {k: v for k, v in d.items() if k != "cell_size"}
        return MultiResolutionConfig([config_from_dict({**base, "cell_size": c}, f"{where}.cell_size[{i}]")
                                      for i, c in enumerate(cell)])
    try:
        return FieldConfig(**dict(d))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None


def load_config(source: str | Path | Mapping | AnyConfig) -> AnyConfig:
    """Config from a typed config, a dict, or a YAML file path."""
    if isinstance(source, (FieldConfig, MultiResolutionConfig, HybridConfig)):
        return source
    if isinstance(source, (str, Path)):
        import yaml

        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"field spec file not found: {path}")
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise ValueError(f"{path}: not valid YAML: {exc}") from None
        return config_from_dict(data, where=str(path))
    return config_from_dict(source)


def build(spec: str | Path | Mapping | AnyConfig) -> Field | MultiResolution | Hybrid:
    """Build a field (or multi-resolution / hybrid module) from a spec; see the module docstring."""
    cfg = load_config(spec)
    if isinstance(cfg, MultiResolutionConfig):
        return MultiResolution([build(level) for level in cfg.levels])
    if isinstance(cfg, HybridConfig):
        return Hybrid({name: build(s) for name, s in cfg.fields.items()})
    cls = KINDS[cfg.kind]
    kwargs: dict[str, Any] = {"cell_size": cfg.cell_size, "grid_shape": cfg.grid_shape, "channels": cfg.channels,
                              "init_std": cfg.init_std}
    if cls.has_rank:
        kwargs["rank"] = cfg.rank
    elif cfg.rank is not None:
        raise ValueError(f"kind {cfg.kind!r} has no rank (got rank={cfg.rank})")
    if cfg.strategy is not None:
        kwargs["strategy"] = cfg.strategy
    return cls(cfg.aabb, **kwargs)
