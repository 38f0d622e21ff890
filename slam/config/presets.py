"""The bundled presets and config files: reading a YAML file, a preset's ``inherit`` chain (parents first), and
merging layers (a later layer's keys win)."""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

from slam.errors import SlamInputError

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


# --------------------------------------------------------------------------------------------------- merging
def deep_merge(base: dict, update: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and k != "options":
            out[k] = deep_merge(out[k], v)
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = copy.deepcopy(v)
    return out


def read_yaml(path: Path, what: str) -> dict:
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
        if rel == "base" or rel.startswith(("representations/", "profiles/")):
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


def preset_chain(name: str, seen: tuple = ()) -> list[dict]:
    """Layers for a preset, parents first (base excluded)."""
    if name in seen:
        raise SlamInputError(f"preset inheritance cycle: {' -> '.join(seen + (name,))}")
    path = _preset_path(name)
    data = read_yaml(path, "config file")
    parent = data.pop("inherit", None)
    if parent is None and "/" in name and not name.endswith((".yaml", ".yml")):
        parent = name.split("/", 1)[0]
    chain = preset_chain(parent, seen + (name,)) if parent not in (None, "base") else []
    return chain + [data]
