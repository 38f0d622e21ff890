"""How a config key is declared: :func:`key` (its default and its one line of meaning), :func:`num` (a numeric key and
its :class:`Range`), :func:`choice` (one of a set of values, or of a registry's names read when checked:
:class:`RegistryNames`), and the common ranges. The schema (:mod:`slam.config.schema`) declares every key with them;
:mod:`slam.config.validate` checks values against them."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any


class RegistryNames(Sequence):
    """The names of a registry (a dict such as :data:`tdfields.KINDS`), sorted, as they are when read: a
    :func:`choice` over them accepts what is registered after this module is imported too."""

    def __init__(self, registry: Mapping[str, Any]):
        self._registry = registry

    def __getitem__(self, i):
        return tuple(self)[i]

    def __len__(self) -> int:
        return len(self._registry)

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and name in self._registry

    def __iter__(self):
        return iter(sorted(self._registry))

    def __repr__(self) -> str:
        return f"RegistryNames{tuple(self)!r}"


# --------------------------------------------------------------------------------------------------- ranges
@dataclass(frozen=True)
class Range:
    """The allowed values of a numeric key: ``lo``/``hi`` bounds (None: unbounded), each closed unless
    ``*_open``. Lists are checked element by element; ``None`` passes where the key is optional."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def ok(self, v: float) -> bool:
        if not math.isfinite(v):  # NaN, and infinities: no key means "unbounded" by .inf
            return False
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        if self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi):
            return False
        return True

    def __str__(self) -> str:
        def fmt(v: float) -> str:
            return str(int(v)) if float(v).is_integer() and abs(v) < 1e16 else f"{v:g}"

        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {fmt(self.lo)}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {fmt(self.hi)}")
        return " and ".join(parts) or "any number"


def key(default, doc: str = "", type_name: str | None = None, metadata: dict | None = None, **kw):
    """A config key's dataclass field: ``default`` (a callable is a factory, for mutable values and sections) and its
    one line of meaning ``doc``, which the configuration reference prints (:mod:`slam.config.reference`;
    ``type_name``: the type it shows where the annotation says too little, e.g. ``Any``). ``metadata``: what
    :mod:`slam.config.validate` checks (``range``, ``choices``)."""
    meta = {**(metadata or {}), "doc": doc}
    if type_name is not None:
        meta["type"] = type_name
    if callable(default):
        return field(default_factory=default, metadata=meta, **kw)
    return field(default=default, metadata=meta, **kw)


def num(default, lo=None, hi=None, lo_open=False, hi_open=False, doc: str = "", **kw):
    """A numeric :func:`key` with its range (see :class:`Range`), checked by :func:`load_config`."""
    return key(default, doc, metadata={"range": Range(lo, hi, lo_open, hi_open)}, **kw)


def choice(default, options: tuple | RegistryNames, doc: str = "", **kw):
    """A :func:`key` whose value must be one of ``options`` (a :class:`RegistryNames` is read as a config is
    checked)."""
    options = options if isinstance(options, RegistryNames) else tuple(options)
    return key(default, doc, metadata={"choices": options}, **kw)


# every numeric key has a finite upper bound too: a value no run could use (1e30 pixels, a 1e9-iteration call) is
# refused when the config is read instead of failing an allocation mid-run; the bounds are far above any preset
BIG = 10_000_000
COUNT = {"lo": 1, "hi": BIG}          # iteration and pixel counts, sizes
POSITIVE = {"lo": 0, "lo_open": True, "hi": 1e6}   # lengths, scales
RATE = {"lo": 0, "lo_open": True, "hi": 10.0}      # learning rates
NONNEG = {"lo": 0, "hi": BIG}         # weights, margins, counts that may be 0
FRACTION = {"lo": 0, "hi": 1}
METRES = {"lo": 0, "lo_open": True, "hi": 1000.0}  # lengths in metres
