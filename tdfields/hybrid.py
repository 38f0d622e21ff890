"""Hybrid: named fields of any kinds (e.g. CP geometry + Six-axis appearance) in one module."""

from __future__ import annotations

from typing import Iterable, Mapping

import torch
from torch import nn


class Hybrid(nn.ModuleDict):
    """A dictionary of fields queried together or by name.

    Args:
        fields: name -> field (any :class:`tdfields.Field` or :class:`tdfields.MultiResolution`). A name must be a
            valid module name (no ``.``) that is not a method of this class (``names``, ``spec``, ``forward``...).

    ``hybrid(points)`` returns ``{name: [..., out_dim_name]}`` for ``[..., 3]`` world points in metres;
    ``hybrid(points, names=["geometry"])`` queries only those; ``hybrid["geometry"]`` is the field itself.
    Parameter names start with the field's name: ``geometry.levels.0.factors.x``. :func:`tdfields.report` lists
    every field inside with a combined total.

    State dicts written before Hybrid held its fields directly (``fields.geometry.levels.0.factors.x``) still load.
    """

    def __init__(self, fields: Mapping[str, nn.Module]):
        super().__init__()
        if not fields:
            raise ValueError("Hybrid needs at least one named field")
        for name, module in fields.items():
            if hasattr(Hybrid, name):
                raise ValueError(f"Hybrid: field name {name!r} is taken by a Hybrid attribute; choose another")
            self[name] = module

    def __getitem__(self, name: str) -> nn.Module:
        if name not in self._modules:
            raise KeyError(f"Hybrid has no field {name!r}; it has {list(self._modules)}")
        return self._modules[name]

    def names(self) -> list[str]:
        """Field names in insertion order."""
        return list(self.keys())

    def forward(self, points: torch.Tensor, names: Iterable[str] | None = None) -> dict[str, torch.Tensor]:
        """``[..., 3]`` world metres -> ``{name: [..., C_name]}`` for the requested (default: all) fields."""
        return {name: self[name](points) for name in (self.names() if names is None else names)}

    def num_parameters(self) -> int:
        """Total trainable scalars of all fields."""
        return sum(p.numel() for p in self.parameters())

    def memory_bytes(self) -> int:
        """Bytes held by all fields' parameters."""
        return sum(f.memory_bytes() for f in self.values())

    def spec(self) -> dict:
        """Config dict: ``{"kind": "hybrid", "fields": {name: spec}}``."""
        return {"kind": "hybrid", "fields": {name: f.spec() for name, f in self.items()}}

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # Checkpoints from before Hybrid was a ModuleDict name every tensor "<prefix>fields.<name>.": drop the
        # "fields." so they load (not when a field is itself called "fields": then the old names are the new ones).
        old = prefix + "fields."
        if "fields" not in self._modules:
            for key in [k for k in state_dict if k.startswith(old)]:
                rest = key[len(old):]
                if rest.split(".", 1)[0] in self._modules and prefix + rest not in state_dict:
                    state_dict[prefix + rest] = state_dict.pop(key)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
