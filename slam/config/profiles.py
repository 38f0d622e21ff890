"""Profiles: how much work a run spends, apart from what the data are (``slam/configs/profiles/<name>.yaml``).

A preset describes the data (camera, crop, depth scale, a published box); a profile the budget: ``realtime`` (the
CPU default), ``quality`` (the careful CPU budget) and ``paper`` (the published ESLAM / LRSLAM settings, the default
with ``device: cuda``). A profile file holds config keys for every dataset kind, and under ``kinds:`` a layer per
dataset kind (``data.kind``) where that kind's budget was set on its own. Old preset names that named a budget live
on as :data:`ALIASES`: a data preset, a profile and the keys that made the old preset differ.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from slam.config.presets import CONFIG_DIR, read_yaml
from slam.errors import SlamInputError

__all__ = ["ALIASES", "DEFAULT_PROFILES", "PROFILES", "Alias", "default_profile", "describe", "profile_layers"]

PROFILE_DIR = CONFIG_DIR / "profiles"
#: the bundled profiles, cheapest first
PROFILES = ("realtime", "quality", "paper")
#: the profile a run gets when none is named, per device type
DEFAULT_PROFILES = {"cpu": "realtime", "cuda": "paper"}


@dataclass(frozen=True)
class Alias:
    """An old preset name: ``preset`` read with ``profile`` and ``overrides`` (``key=value``, as on the command line)
    gives its config."""

    preset: str
    profile: str
    overrides: tuple[str, ...] = ()

    def command(self) -> str:
        """The options that replace the old name, as a user types them."""
        return " ".join(("--config", self.preset, "--profile", self.profile, *self.overrides))


_RPY_BOX = ("scene.grow=false",)
#: old preset name -> what replaces it (each gives the old preset's settings; tests/slam/config check it)
ALIASES = {
    "tum/fr1_rpy-cpu": Alias("tum/fr1_rpy", "quality", _RPY_BOX),
    "tum/fr1_rpy-cpu-gn": Alias("tum/fr1_rpy", "quality", (*_RPY_BOX, "tracking.optimizer=gauss_newton",
                                                           "tracking.gn_prior=0.03")),
    "tum/fr1_rpy-cpu-fast": Alias("tum/fr1_rpy", "realtime", _RPY_BOX),
    "tum/fr1_rpy-eslam-cpu": Alias("tum/fr1_rpy", "paper", (
        "tracking.iters=30", "tracking.pixels=1000", "mapping.every_frame=4", "mapping.keyframe_every=4",
        "mapping.iters=20", "mapping.pixels=2000", "mapping.iters_first=200")),
}


def default_profile(device: str) -> str:
    """The profile of a run on ``device`` (``cpu``, ``cuda`` or ``cuda:N``) that names none."""
    return DEFAULT_PROFILES["cuda" if str(device).startswith("cuda") else "cpu"]


def _profile_path(name: str) -> Path:
    if name.endswith((".yaml", ".yml")):
        return Path(name)
    if name not in PROFILES:
        raise SlamInputError(f"unknown profile {name!r}; choose from {', '.join(PROFILES)} (or a .yaml file)")
    return PROFILE_DIR / f"{name}.yaml"


def profile_layers(name: str, kind: str) -> list[dict]:
    """The config layers of profile ``name`` (a bundled name or a YAML file's path) for data of ``kind``: its keys
    for every kind, then its layer for ``kind`` if it has one.

    Raises:
        SlamInputError: an unknown profile, a missing or malformed file, or ``kinds`` that is not a mapping."""
    path = _profile_path(name)
    data = read_yaml(path, "profile file")
    kinds = data.pop("kinds", None) or {}
    if not isinstance(kinds, dict) or not all(isinstance(v, dict) for v in kinds.values()):
        raise SlamInputError(f"{path}: 'kinds' must map dataset kinds to config layers")
    if "inherit" in data:
        raise SlamInputError(f"{path}: a profile does not inherit; it holds every key it sets")
    return [data, kinds[kind]] if kind in kinds else [data]


def describe(name: str) -> str:
    """The first comment line of a bundled profile's file: what it is for and what it costs."""
    for line in _profile_path(name).read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
    return ""
