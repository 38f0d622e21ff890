"""A validated :class:`~slam.config.schema.Config` from plain data: each value coerced to its field's type and
checked against its range or choices (:mod:`slam.config.schema`), keys that moved (:data:`MOVED`), and the checks
across keys."""

from __future__ import annotations

import copy
import dataclasses
import math
import re
from typing import Any, Union, get_args, get_origin, get_type_hints

from slam.config.schema import SECTION_RANGES, Config, Range
from slam.errors import SlamInputError


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
        # int(.inf) raises OverflowError and int(.nan) ValueError: refuse them here, with the key's name
        if (isinstance(value, bool) or not isinstance(value, (int, float))
                or isinstance(value, float) and (not math.isfinite(value) or int(value) != value)):
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
        _check_value(prefix + k, kwargs[k], fields_[k].metadata, SECTION_RANGES.get(cls))
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
    if cfg.mapping.max_keyframes in (1, 2):
        # the store keeps the first keyframe and the last two (the window always has them): fewer than 3 would
        # have to drop one of those
        raise SlamInputError(f"config key 'mapping.max_keyframes' = {cfg.mapping.max_keyframes} is out of range: "
                             "must be 0 (keep every keyframe) or >= 3 (the first and the last two are always kept)")
    # mapping.keyframe_spill_dir is not checked here: it is scratch, and a run folder's config is also read where
    # it is never used (lrslam mesh, a resume on another machine); slam.engine.setup.check_spill_dir checks it
    # where a fresh run starts
    if cfg.mapper_process and not cfg.parallel:
        raise SlamInputError("config key 'mapper_process' = true needs 'parallel' = true (sequential mode maps inline, "
                             "in the tracker's own process)")
    if cfg.tracking.icp_normals % 2 == 0:
        raise SlamInputError(f"config key 'tracking.icp_normals' = {cfg.tracking.icp_normals} must be odd (a square "
                             "of pixels around each one)")
    if len(cfg.tracking.ignore_edge) != 2:
        raise SlamInputError(f"config key 'tracking.ignore_edge' must be [rows, columns], got {cfg.tracking.ignore_edge!r}")
