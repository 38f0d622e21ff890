"""Hybrid: named fields of any kinds (e.g. CP geometry + Six-axis appearance) in one module."""

from __future__ import annotations

from typing import Iterable, Mapping

import torch
from torch import nn


class Hybrid(nn.Module):
    """A dictionary of fields queried together or by name.

    Args:
        fields: name -> field (any :class:`tdfields.Field` or :class:`tdfields.MultiResolution`).

    ``hybrid(points)`` returns ``{name: [..., out_dim_name]}`` for ``[..., 3]`` world points in metres;
    ``hybrid(points, names=["geometry"])`` queries only those; ``hybrid["geometry"]`` is the field itself.
    :func:`tdfields.report` lists every field inside with a combined total.
    """

    def __init__(self, fields: Mapping[str, nn.Module]):
        super().__init__()
        if not fields:
            raise ValueError("Hybrid needs at least one named field")
        self.fields = nn.ModuleDict(dict(fields))

    def __getitem__(self, name: str) -> nn.Module:
        if name not in self.fields:
            raise KeyError(f"Hybrid has no field {name!r}; it has {list(self.fields)}")
        return self.fields[name]

    def __contains__(self, name: str) -> bool:
        return name in self.fields

    def names(self) -> list[str]:
        """Field names in insertion order."""
        return list(self.fields)

    @property
    def out_dims(self) -> dict[str, int]:
        """Name -> feature width."""
        return {name: f.out_dim for name, f in self.fields.items()}

    def forward(self, points: torch.Tensor, names: Iterable[str] | None = None) -> dict[str, torch.Tensor]:
        """``[..., 3]`` world metres -> ``{name: [..., C_name]}`` for the requested (default: all) fields."""
        return {name: self[name](points) for name in (self.names() if names is None else names)}

    def num_parameters(self) -> int:
        """Total trainable scalars of all fields."""
        return sum(p.numel() for p in self.parameters())

    def memory_bytes(self) -> int:
        """Bytes held by all fields' parameters."""
        return sum(f.memory_bytes() for f in self.fields.values())

    def spec(self) -> dict:
        """Config dict: ``{"kind": "hybrid", "fields": {name: spec}}``."""
        return {"kind": "hybrid", "fields": {name: f.spec() for name, f in self.fields.items()}}
