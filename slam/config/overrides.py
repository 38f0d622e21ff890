"""``key=value`` overrides (the command line's): parsed into a nested mapping, and their short aliases."""

from __future__ import annotations

import yaml

from slam.errors import SlamInputError


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


def alias(over: dict) -> dict:
    """Short override aliases: ``bound=auto`` means ``scene.bound``."""
    over = dict(over)
    if "bound" in over:
        over.setdefault("scene", {})
        over["scene"] = {**over["scene"], "bound": over.pop("bound")}
    return over
