"""Config mappings as dotted keys (``tracking.iters``): :func:`flatten`, and the keys two configs differ in."""

from __future__ import annotations


def flatten(d: dict, prefix: str = "") -> dict:
    """A nested config mapping as ``{"dotted.key": value}`` (an empty mapping stays one value)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def differing_keys(a: dict, b: dict, ignore: tuple[str, ...] = ()) -> list[str]:
    """The dotted keys, sorted, whose values differ between two config mappings (missing counts as None), except
    those in ``ignore``."""
    fa, fb = flatten(a), flatten(b)
    return sorted(k for k in set(fa) | set(fb) if k not in ignore and fa.get(k) != fb.get(k))
