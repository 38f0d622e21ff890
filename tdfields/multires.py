"""Multi-resolution: several fields (usually the same kind, coarse + fine) queried and concatenated."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from tdfields.bounds import contains
from tdfields.field import COMPLEXITIES, Field
from tdfields.ops import evaluate, grid_coords
from tdfields.program import concat


class MultiResolution(nn.Module):
    """Concatenation of the features of several fields: ``[..., 3] -> [..., sum(level.out_dim)]``.

    LRSLAM and ESLAM use two levels of the same kind (coarse 0.24 m, fine 0.06 / 0.03 m) and feed the
    concatenated 64 channels to the decoder. Levels may be of different kinds.

    Args:
        levels: the fields, coarse first by convention; their order is the order of the output channels.
    """

    kind = "multires"

    def __init__(self, levels: Sequence[Field]):
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
        """``[..., 3]`` world metres -> ``[..., out_dim]`` (levels concatenated in order).

        When every level is a :class:`tdfields.Field`, their query plans are concatenated and evaluated in one
        pass (one fused kernel call for coarse + fine).
        """
        if points.shape[-1] != 3:
            raise ValueError(f"MultiResolution: points must have shape [..., 3], got {tuple(points.shape)}")
        if not all(isinstance(level, Field) for level in self.levels):
            return torch.cat([level(points) for level in self.levels], dim=-1)
        lead = points.shape[:-1]
        flat = points.reshape(-1, 3)
        coords = grid_coords(flat, [level.aabb for level in self.levels], [level.grid_shape for level in self.levels])
        plans = [level.plan_query(c) for level, c in zip(self.levels, coords)]
        program = concat([p for p, _, _ in plans])
        coords = torch.stack([c for _, _, c in plans])
        out = evaluate(program, [t for _, tensors, _ in plans for t in tensors], coords)
        return out.reshape(*lead, self.out_dim)

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
