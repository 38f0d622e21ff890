"""Reading a configuration: YAML presets layered base <- representation <- dataset <- scene, plus ``key=value``
overrides, into a validated :class:`Config`, and writing it back.

The pieces live beside this module: :mod:`slam.config.presets` (preset files, ``inherit`` chains, merging),
:mod:`slam.config.overrides` (``key=value`` parsing), :mod:`slam.config.validate` (types, ranges, moved keys) and
:mod:`slam.config.dotted` (dotted keys); the names they offer that this module offered stay importable from here."""

from __future__ import annotations

import logging
from pathlib import Path

import yaml

from slam.config.schema import NONNEG, REPRESENTATIONS, Config, Range
from slam.config.dotted import differing_keys, flatten
from slam.config.overrides import alias, parse_overrides
from slam.config.profiles import ALIASES, default_profile, profile_layers
from slam.config.presets import CONFIG_DIR, deep_merge, preset_chain, read_yaml, list_presets
from slam.config.validate import MOVED, config_from_dict
from slam.errors import SlamInputError
from slam.files import atomic_write_text

log = logging.getLogger(__name__)

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


def _last(layers: list[dict], section: str | None, key: str, default):
    value = default
    for layer in layers:
        node = layer.get(section, {}) if section else layer
        if isinstance(node, dict) and key in node:
            value = node[key]
    return value


def load_config(preset: str | None = "synthetic", overrides: list[str] | dict | None = None,
                profile: str | None = None) -> Config:
    """Resolve a preset (name or YAML path), a profile and overrides into a validated :class:`Config`.

    Layers, each overriding the one before: ``base.yaml``, the representation block the layers name
    (``representations/<name>.yaml``), the profile (:mod:`slam.config.profiles`: its keys for every dataset kind,
    then its layer for the preset's ``data.kind``), the preset's parents, the preset, the overrides.

    Args:
        preset: a bundled preset's name, an old name in :data:`~slam.config.profiles.ALIASES` (its preset, profile
            and keys), or a YAML file's path.
        overrides: ``["key=value", ...]`` or a nested mapping; ``profile=NAME`` among them names the profile.
        profile: ``realtime``, ``quality``, ``paper`` or a profile YAML file; None: the overrides' ``profile``,
            else the device's default (:data:`~slam.config.profiles.DEFAULT_PROFILES`: realtime on the CPU, paper
            on CUDA).

    Raises:
        SlamInputError: unknown preset, profile, file, key, representation, or a badly typed / out-of-range value.
    """
    preset = preset or "synthetic"
    base = read_yaml(CONFIG_DIR / "base.yaml", "base config")
    over = alias(dict(overrides) if isinstance(overrides, dict) else parse_overrides(overrides))
    named = over.pop("profile", None)
    if named is not None and profile is not None and str(named) != profile:
        raise SlamInputError(f"two profiles named: {profile!r} and profile={named!r}")
    profile = profile if profile is not None else (str(named) if named is not None else None)
    old = ALIASES.get(preset)
    fixed: dict = {}
    if old is not None:
        if profile is not None and profile != old.profile:
            raise SlamInputError(f"preset '{preset}' is the old name of {old.command()}: give those instead of "
                                 f"the old name with a profile")
        log.warning("preset '%s' is now %s", preset, old.command())
        profile, fixed = old.profile, parse_overrides(list(old.overrides))
    chain = preset_chain(old.preset if old is not None else preset)
    given = [base] + chain + [fixed, over]
    if profile is None:
        profile = default_profile(str(_last(given, None, "device", "cpu")))
    kind = str(_last(given, "data", "kind", "auto"))
    layers = profile_layers(profile, kind) + chain + [fixed, over]
    rep = _representation([base] + layers)
    merged = deep_merge(base, read_yaml(CONFIG_DIR / "representations" / f"{rep}.yaml", "representation block"))
    for layer in layers:
        merged = deep_merge(merged, layer)
    if not merged.get("parallel", True) and _last(chain + [fixed, over], None, "mapper_process", None) is None:
        merged["mapper_process"] = False  # the profile's mapping process serves parallel mode; sequential maps inline
    if "name" not in over:
        merged["name"] = Path(preset).stem if preset.endswith((".yaml", ".yml")) else preset
    merged["profile"] = profile
    return config_from_dict(merged)


def save_config(cfg: Config, path: str | Path) -> None:
    """Write ``cfg`` as YAML durably (:mod:`slam.files`: a full disk is one line naming the file)."""
    atomic_write_text(Path(path), yaml.safe_dump(cfg.to_dict(), sort_keys=False), "config")
