"""The configuration reference, docs/configuration.md: every key of the schema (:mod:`slam.config.schema`) with its
type, default, range or choices and its one line of meaning, and the keys each preset, profile, representation
block and old preset name sets, read from their YAML files.

``python docs/scripts/config_reference.py`` writes the page from :func:`render_reference`; a test fails when the
committed page differs from it, so a key added without its ``doc=`` or a changed default shows there. The output
depends on the schema and the bundled YAML files only (kinds registered at run time are left out)."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any, Union, get_args, get_origin, get_type_hints

import tdfields
from slam.config.dotted import flatten
from slam.config.presets import CONFIG_DIR, list_presets, read_yaml
from slam.config.profiles import ALIASES, PROFILE_DIR, PROFILES
from slam.config.schema import FIELD_KINDS, SECTION_RANGES, Config

__all__ = ["KeyDoc", "render_reference", "schema_keys", "value_text"]

PAGE = "docs/configuration.md"
SCRIPT = "docs/scripts/config_reference.py"


@dataclass(frozen=True)
class KeyDoc:
    """One key of the schema as the reference prints it: ``key`` dotted, ``type`` and ``allowed`` (range or choices;
    ``""``: any value of the type) as text, ``default`` the value, ``doc`` its meaning; ``group``: a mapping of
    keys (``tracking.weights``), whose own keys follow it."""

    key: str
    type: str
    default: Any
    allowed: str
    doc: str
    group: bool = False


def value_text(v: Any) -> str:
    """``v`` as it is written in YAML or a ``key=value`` override (``null``, ``true``, ``[0.24, 0.06]``...)."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return v if v else '""'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(value_text(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {value_text(x)}" for k, x in v.items()) + "}"
    return repr(v)


def _type_text(tp: Any, meta, default: Any) -> str:
    if "type" in meta:
        return meta["type"]
    if get_origin(tp) is Union:
        inner = [a for a in get_args(tp) if a is not type(None)]
        return _type_text(inner[0], {}, default) + " or null"
    if tp is list or get_origin(tp) is list:
        kinds = sorted({type(x).__name__ for x in default or []})
        return "list of " + " or ".join(kinds) if kinds else "list"
    if dataclasses.is_dataclass(tp) or tp is dict:
        return "mapping"
    return {bool: "bool", int: "int", float: "float", str: "string"}.get(tp, str(tp))


def _allowed_text(meta, section_range) -> str:
    choices = meta.get("choices")
    if choices is FIELD_KINDS:
        # tdfields' own kinds: a kind registered by a plugin or a test is accepted too, but not printed
        choices = sorted(n for n, c in tdfields.KINDS.items() if c.__module__.startswith("tdfields."))
    if choices is not None:
        return ", ".join(f"`{value_text(c)}`" for c in choices)
    rng = meta.get("range", section_range)
    return "" if rng is None else str(rng)


def schema_keys(cls=Config, default=None, prefix: str = "") -> list[KeyDoc]:
    """Every key of ``cls`` (the whole schema by default) in declaration order, a section's keys after the top-level
    ones; ``default``: the instance whose values are the defaults (a section's own default, e.g. ``appearance``'s)."""
    default = cls() if default is None else default
    hints = get_type_hints(cls)
    top, nested = [], []
    for f in dataclasses.fields(cls):
        tp, value, name = hints[f.name], getattr(default, f.name), prefix + f.name
        doc = f.metadata.get("doc", "")
        if dataclasses.is_dataclass(tp):
            sub = schema_keys(tp, value, name + ".")
            if prefix:  # a mapping of keys inside a section: a row of its own, then its keys
                top += [KeyDoc(name, "mapping", dataclasses.asdict(value), "", doc, group=True), *sub]
            else:
                nested += sub
            continue
        top.append(KeyDoc(name, _type_text(tp, f.metadata, value), value,
                          _allowed_text(f.metadata, SECTION_RANGES.get(cls)), doc))
    return top + nested


def _cell(text: str) -> str:
    # a bare pipe would end the table cell
    return text.replace("|", "\\|").replace("\n", " ")


def _key_table(keys: list[KeyDoc]) -> list[str]:
    rows = ["| key | type | default | range / choices | meaning |", "|---|---|---|---|---|"]
    for k in keys:
        rows.append(f"| `{k.key}` | {_cell(k.type)} | `{_cell(value_text(k.default))}` | {_cell(k.allowed)} | "
                    f"{_cell(k.doc)} |")
    return rows


def _sections() -> list[tuple[str, str, list[KeyDoc]]]:
    """``(title, intro, keys)``: the top-level keys, then one per section in the schema's order."""
    keys = schema_keys()
    docs = {f.name: f.metadata.get("doc", "") for f in dataclasses.fields(Config)}
    out = [("Top-level keys", "Keys outside any section.", [k for k in keys if "." not in k.key])]
    for name, doc in docs.items():
        section = [k for k in keys if k.key.startswith(name + ".")]
        if section:
            out.append((f"`{name}`", doc, section))
    return out


def _summary(path) -> str:
    """The first sentence of the comment a YAML file starts with."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("# ").strip())
    return re.split(r"(?<=\.)\s+(?=[A-Z])", " ".join(lines), maxsplit=1)[0]


def _sets(layer: dict) -> str:
    return ", ".join(f"`{k}={value_text(v)}`" for k, v in flatten(layer).items())


def _layer_rows() -> list[str]:
    """The table of what each bundled file sets (base.yaml: where it departs from the schema's defaults)."""
    defaults = flatten(Config().to_dict())
    base = {k: v for k, v in flatten(read_yaml(CONFIG_DIR / "base.yaml", "base config")).items()
            if defaults.get(k) != v}
    rows = ["| chosen by | what it is | keys it sets |", "|---|---|---|",
            f"| every run | slam/configs/base.yaml, where it departs from the defaults above | {_sets(base)} |"]
    for rep in sorted(p.stem for p in (CONFIG_DIR / "representations").glob("*.yaml")):
        path = CONFIG_DIR / "representations" / f"{rep}.yaml"
        rows.append(f"| `representation={rep}` | {_cell(_summary(path))} | {_sets(read_yaml(path, 'block'))} |")
    for name in PROFILES:
        data = read_yaml(PROFILE_DIR / f"{name}.yaml", "profile file")
        kinds = data.pop("kinds", None) or {}
        rows.append(f"| `--profile {name}` | {_cell(_summary(PROFILE_DIR / f'{name}.yaml'))} | {_sets(data) or '(only per data kind)'} |")
        rows += [f"| `--profile {name}`, data kind `{kind}` | its layer for `data.kind: {kind}` | {_sets(layer)} |"
                 for kind, layer in kinds.items()]
    # a dataset's preset, then the presets that build on it
    for name in sorted(list_presets(), key=lambda n: (n.split("/")[0], n.count("/"), n)):
        path = CONFIG_DIR / f"{name}.yaml"
        data = read_yaml(path, "config file")
        parent = data.pop("inherit", None) or (name.split("/", 1)[0] if "/" in name else None)
        what = " ".join(filter(None, [_summary(path), f"(on top of `{parent}`)" if parent else ""]))
        rows.append(f"| `--config {name}` | {_cell(what)} | {_sets(data)} |")
    for old, alias in ALIASES.items():
        sets = ", ".join(f"`{o}`" for o in (f"profile={alias.profile}", *alias.overrides))
        rows.append(f"| `--config {old}` | an old preset name: `{alias.command()}` | {sets} |")
    return rows


_INTRO = f"""# Configuration reference

<!-- Written by `python {SCRIPT}` from slam/config/schema/ and slam/configs/: edit those and run it,
not this page (a test fails when the page is stale). -->

Every key of a run's configuration, with its type, default, allowed values and meaning. A run's `config.yaml` holds
them all. They are read in layers, each one's keys overriding the layer's before it
(`slam.config.load_config`):

1. `slam/configs/base.yaml`, which every run starts from (where it departs from the defaults below:
   [the last table](#presets-profiles-and-representations));
2. the representation block, `representation=NAME`: `slam/configs/representations/NAME.yaml`;
3. the profile, the budget apart from the data: `--profile realtime`, `quality`, `paper` or a YAML file
   (default: `realtime` on the CPU, `paper` with `--device cuda`): its keys for every dataset kind, then its
   layer for the preset's `data.kind`;
4. the preset, the data: `--config NAME` (a file under `slam/configs/`) or a YAML file's path, after the preset
   it builds on (its `inherit` key, else its folder's dataset preset: `tum/fr1_rpy` builds on `tum`);
5. `key=value` overrides on the command line, dotted keys with YAML values:
   `lrslam run --config tum/fr1_rpy tracking.iters=20 tracking.ignore_edge=[20,20]`. `profile=NAME` names the
   profile as `--profile` does, `bound=...` is `scene.bound`; `--data DIR`, `--device` and `--realtime` set
   `data.path`, `device` and `data.realtime`.

Every value is checked as it is read: an unknown key, a value of the wrong type or out of its range stops with one
line naming the key and what is allowed. Defaults are ESLAM's unless the meaning says "(ours)". A range applies to
each element of a list. The meanings are the keys' `doc=` in `slam/config/schema/`.
"""


def render_reference() -> str:
    """The configuration reference page (Markdown), the same for the same schema and YAML files."""
    lines = [_INTRO]
    for title, intro, keys in _sections():
        lines += [f"## {title}", "", intro, "", *_key_table(keys), ""]
    lines += ["## Presets, profiles and representations", "",
              "What each bundled file sets, as `key=value` (a profile, then its layer per dataset kind; a preset "
              "without the keys of the preset it builds on).", "", *_layer_rows(), ""]
    return "\n".join(lines)
