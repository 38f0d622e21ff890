"""Reading a configuration: YAML presets layered base <- representation <- dataset <- scene, plus ``key=value``
overrides, into a validated :class:`Config`, and writing it back.

The pieces live beside this module: :mod:`slam.config.presets` (preset files, ``inherit`` chains, merging),
:mod:`slam.config.overrides` (``key=value`` parsing), :mod:`slam.config.validate` (types, ranges, moved keys) and
:mod:`slam.config.dotted` (dotted keys); the names they offer that this module offered stay importable from here."""

from __future__ import annotations

from pathlib import Path

import yaml

from slam.config.schema import NONNEG, REPRESENTATIONS, Config, Range
from slam.config.dotted import differing_keys, flatten
from slam.config.overrides import alias, parse_overrides
from slam.config.presets import CONFIG_DIR, deep_merge, preset_chain, read_yaml, list_presets
from slam.config.validate import MOVED, config_from_dict
from slam.errors import SlamInputError
from slam.files import atomic_write_text

# the schema's names too: all were importable from here before the split
__all__ = ["CONFIG_DIR", "MOVED", "NONNEG", "REPRESENTATIONS", "Config", "Range", "check_representation", "config_from_dict", "differing_keys",
           "flatten", "list_presets", "load_config", "parse_overrides", "save_config"]


def check_representation(rep: str) -> str:
    """``rep`` when it names a block under ``slam/configs/representations/``.

    Raises:
        SlamInputError: it does not (the message lists the choices)."""
    if rep not in REPRESENTATIONS:
        raise SlamInputError(f"unknown representation '{rep}'; choose from {', '.join(REPRESENTATIONS)}")
    return rep


def _representation(layers: list[dict]) -> str:
    rep = "lrslam"
    for layer in layers:
        rep = layer.get("representation", rep)
    return check_representation(rep)


def load_config(preset: str | None = "synthetic", overrides: list[str] | dict | None = None) -> Config:
    """Resolve a preset (name or YAML path) plus overrides into a validated :class:`Config`.

    Layers, each overriding the one before: ``base.yaml``, the representation block the layers name
    (``representations/<name>.yaml``), the preset's parents, the preset, the overrides.

    Raises:
        SlamInputError: unknown preset, file, key, representation, or a badly typed / out-of-range value.
    """
    preset = preset or "synthetic"
    base = read_yaml(CONFIG_DIR / "base.yaml", "base config")
    over = overrides if isinstance(overrides, dict) else parse_overrides(overrides)
    layers = preset_chain(preset) + [alias(over)]
    rep = _representation([base] + layers)
    merged = deep_merge(base, read_yaml(CONFIG_DIR / "representations" / f"{rep}.yaml", "representation block"))
    for layer in layers:
        merged = deep_merge(merged, layer)
    if "name" not in over:
        merged["name"] = Path(preset).stem if preset.endswith((".yaml", ".yml")) else preset
    return config_from_dict(merged)


def save_config(cfg: Config, path: str | Path) -> None:
    """Write ``cfg`` as YAML durably (:mod:`slam.files`: a full disk is one line naming the file)."""
    atomic_write_text(Path(path), yaml.safe_dump(cfg.to_dict(), sort_keys=False), "config")
