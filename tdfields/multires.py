"""Multi-resolution: several fields (usually the same kind, coarse + fine) queried and concatenated."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from tdfields.bounds import contains
from tdfields.field import COMPLEXITIES, Field, Grid, query
from tdfields.program import Plan, concat_plans


class MultiResolution(nn.Module):
    """Concatenation of the features of several fields: ``[..., 3] -> [..., sum(level.out_dim)]``.

    LRSLAM and ESLAM use two levels of the same kind (coarse 0.24 m, fine 0.06 / 0.03 m) and feed the
    concatenated 64 channels to the decoder. Levels may be of different kinds.

    Args:
        levels: the fields (or multi-resolution stacks), coarse first by convention; their order is the order of
            the output channels.

    A query is planned from the levels (:meth:`plan_at`): their plans concatenated into one, so coarse + fine run
    in one fused kernel call, nested stacks included.
    """

    kind = "multires"

    def __init__(self, levels: Sequence[Field | MultiResolution]):
        super().__init__()
        levels = list(levels)
        if not levels:
            raise ValueError("MultiResolution needs at least one level")
        for i, level in enumerate(levels):
            if not isinstance(level, (Field, MultiResolution)):
                raise TypeError(f"MultiResolution level {i} is a {type(level).__name__}, not a tdfields.Field")
        self.levels = nn.ModuleList(levels)

    @property
    def out_dim(self) -> int:
        """Sum of the levels' widths."""
        return sum(level.out_dim for level in self.levels)

    @property
    def aabb(self) -> torch.Tensor:
        """``(3, 2)`` union of the levels' boxes, metres."""
        boxes = torch.stack([level.aabb for level in self.levels])
        return torch.stack([boxes[:, :, 0].min(0).values, boxes[:, :, 1].max(0).values], dim=-1)

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """The finest level's samples per axis."""
        return max((level.grid_shape for level in self.levels), key=lambda s: s[0] * s[1] * s[2])

    @property
    def complexity(self) -> str:
        """The steepest growth among the levels."""
        return max((level.complexity for level in self.levels), key=COMPLEXITIES.index)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """``[..., 3]`` world metres -> ``[..., out_dim]`` (levels concatenated in order), in one evaluation of
        the plan of all levels (:func:`tdfields.plan`)."""
        return query(self, points)

    def grids(self) -> list[Grid]:
        """The levels' grids in order: ``(aabb, grid_shape)`` of every coordinate set a query reads."""
        return [grid for level in self.levels for grid in level.grids()]

    def plan_at(self, coords: torch.Tensor) -> Plan:
        """One :class:`~tdfields.program.Plan` for all levels: each level's plan at its own coordinate sets of
        ``coords [len(grids()), N, 3]``, concatenated (:func:`tdfields.program.concat_plans`)."""
        plans, start = [], 0
        for level in self.levels:
            stop = start + len(level.grids())
            plans.append(level.plan_at(coords[start:stop]))
            start = stop
        return concat_plans(plans)

    def contains(self, points: torch.Tensor) -> torch.Tensor:
        """``[..., 3]`` -> ``[...]`` bool, inside the union box."""
        return contains(self.aabb, points)

    def num_parameters(self) -> int:
        """Sum of the levels' parameter counts."""
        return sum(p.numel() for p in self.parameters())

    def closed_form_parameters(self) -> int:
        """Sum of the levels' closed-form counts."""
        return sum(level.closed_form_parameters() for level in self.levels)

    def parameter_breakdown(self) -> dict[str, int]:
        """``"levels.<i>.<factor>"`` -> number of scalars."""
        return {f"levels.{i}.{name}": n for i, level in enumerate(self.levels)
                for name, n in level.parameter_breakdown().items()}

    def memory_bytes(self) -> int:
        """Bytes held by all levels' parameters."""
        return sum(level.memory_bytes() for level in self.levels)

    def spec(self) -> dict:
        """Config dict that rebuilds this module (see :func:`tdfields.build`)."""
        return {"kind": "multires", "levels": [level.spec() for level in self.levels]}
