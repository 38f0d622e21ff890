"""The one base class every decomposition derives from.

A kind is fully described by (1) its factors: named channels-last tensors, each spanning one, two or three
of the axes x, y, z, and (2) its product terms: which factors' interpolants multiply (elementwise, then summed
over rank). Everything else (box handling, the query, parameter accounting, resizing, saving) lives here once.
"""

from __future__ import annotations

import math
from typing import ClassVar, Protocol, Sequence

import torch
from torch import nn

from tdfields.bounds import as_aabb, contains, grid_shape_for
from tdfields.ops import evaluate, grid_coords
from tdfields.program import Plan, Program, single

COMPLEXITIES = ("O(n)", "O(n^2)", "O(n^3)")

#: ``(aabb, grid_shape)``: a ``(3, 2)`` box in metres and the samples per axis of one grid a query reads
Grid = tuple[torch.Tensor, tuple[int, int, int]]


class FieldLike(Protocol):
    """What :func:`plan` accepts (and :class:`tdfields.MultiResolution` holds as levels): something that names the
    grids its query reads and plans a query at the points' coordinates in them. :class:`Field` reads one grid,
    :class:`tdfields.MultiResolution` its levels' grids in order."""

    @property
    def out_dim(self) -> int:
        """Width of the features a query returns."""

    def grids(self) -> list[Grid]:
        """``(aabb, grid_shape)`` of every coordinate set the query reads, in the order of its plan's levels."""

    def plan_at(self, coords: torch.Tensor) -> Plan:
        """The :class:`~tdfields.program.Plan` of a query at ``coords [len(grids()), N, 3]``: the points'
        continuous indices in each grid (:func:`tdfields.to_grid_coords`)."""


def plan(field: FieldLike, points: torch.Tensor) -> Plan:
    """The :class:`~tdfields.program.Plan` a query of ``field`` at world points ``[N, 3]`` evaluates: the points'
    coordinates in all of its grids in one pass (:func:`tdfields.ops.grid_coords`), then ``field.plan_at`` of them.

    ``field(points)`` is ``tdfields.ops.evaluate(p.program, p.tensors, p.coords)`` of this plan, so it is also what
    a benchmark of the query (a SLAM mapping step, say) should time.
    """
    grids = field.grids()
    return field.plan_at(grid_coords(points, [box for box, _ in grids], [shape for _, shape in grids]))


def query(field: FieldLike, points: torch.Tensor) -> torch.Tensor:
    """``field``'s features at world points ``[..., 3]`` -> ``[..., out_dim]``: its :func:`plan`, evaluated."""
    if points.shape[-1] != 3:
        raise ValueError(f"{type(field).__name__}: points must have shape [..., 3], got {tuple(points.shape)}")
    p = plan(field, points.reshape(-1, 3))
    return evaluate(p.program, p.tensors, p.coords).reshape(*points.shape[:-1], field.out_dim)


class FactorSpec(tuple):
    """``(axes, width)``: the axes a factor spans (subset of ``(0, 1, 2)`` in order) and its channel width."""

    def __new__(cls, axes: Sequence[int], width: int):
        return super().__new__(cls, (tuple(axes), int(width)))

    @property
    def axes(self) -> tuple[int, ...]:
        return self[0]

    @property
    def width(self) -> int:
        return self[1]


class Field(nn.Module):
    """A feature field ``f: R^3 -> R^C`` over an axis-aligned box, stored as interpolated factor grids.

    Subclasses define :meth:`factor_specs` (which factors exist) and :meth:`terms` (which of them multiply).
    The features are ``sum_terms sum_r prod_{f in term} interp(f)[r*C:(r+1)*C]``. Construct with either
    ``cell_size`` or ``grid_shape``.

    Args:
        aabb: ``[[x0, x1], [y0, y1], [z0, z1]]`` in metres. Stored as a ``(3, 2)`` buffer (never a parameter).
        cell_size: metres between samples; ``n_a = floor(extent_a / cell_size)`` in float32 (ESLAM's rule).
        grid_shape: ``(n_x, n_y, n_z)`` samples per axis, instead of ``cell_size``.
        channels: ``C``, the output width.
        rank: the number of rank-one terms, for kinds that have one.
        init_std: standard deviation of the normal initialisation of every factor.

    Coordinates: points are world metres. Sample 0 lies on the lower face of the box and sample ``n - 1`` on the
    upper face. Points outside the box are clamped to the border (the features there are the border features and
    the coordinate gradient is zero); use :meth:`contains` for a validity mask.
    """

    kind: ClassVar[str] = ""
    complexity: ClassVar[str] = ""
    has_rank: ClassVar[bool] = False
    default_init_std: ClassVar[float] = 0.01
    # > 0 inside tdfields.frozen(...): the only time a kind may cache tensors derived from its factors
    _frozen_depth: int = 0

    def __init__(
        self,
        aabb,
        *,
        cell_size: float | None = None,
        grid_shape: Sequence[int] | None = None,
        channels: int,
        rank: int | None = None,
        init_std: float | None = None,
    ):
        super().__init__()
        name = type(self).__name__
        box = as_aabb(aabb)
        if (cell_size is None) == (grid_shape is None):
            raise ValueError(f"{name}: give exactly one of cell_size or grid_shape")
        if grid_shape is not None:
            shape = tuple(int(n) for n in grid_shape)
            if len(shape) != 3 or min(shape) < 2:
                raise ValueError(f"{name}: grid_shape must be three sample counts >= 2, got {tuple(grid_shape)}")
        else:
            shape = grid_shape_for(box, cell_size)
        if not isinstance(channels, int) or channels < 1:
            raise ValueError(f"{name}: channels must be a positive int, got {channels!r}")
        if self.has_rank:
            if not isinstance(rank, int) or rank < 1:
                raise ValueError(f"{name}: rank must be a positive int, got {rank!r}")
        elif rank is not None:
            raise ValueError(f"{name}: this kind has no rank (got rank={rank})")
        self.register_buffer("aabb", box)
        self.grid_shape: tuple[int, int, int] = shape  # type: ignore[assignment]
        self.channels = channels
        self.rank = rank
        self.cell_size = cell_size
        self.init_std = float(self.default_init_std if init_std is None else init_std)
        self.factors = nn.ParameterDict()
        for fname, spec in self.factor_specs().items():
            size = [shape[a] for a in spec.axes] + [spec.width]
            self.factors[fname] = nn.Parameter(torch.randn(size) * self.init_std)

    # -- what a kind defines -------------------------------------------------------------------------------
    def factor_specs(self) -> dict[str, FactorSpec]:
        """Factor name -> :class:`FactorSpec` (axes spanned, channel width)."""
        raise NotImplementedError

    def terms(self) -> list[tuple[str, ...]]:
        """Product terms: tuples of factor names whose interpolants multiply elementwise (at most 3 per term).

        Every factor of a term has width ``k * C`` (rank-major, channel-minor); the product is summed over the
        ``k`` rank components, and the terms are summed.
        """
        raise NotImplementedError

    # -- the query -------------------------------------------------------------------------------------------
    @property
    def out_dim(self) -> int:
        """Width ``C`` of the features this field returns."""
        return self.channels

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """Query features.

        Args:
            points: ``[..., 3]`` world coordinates in metres. Differentiable; never detached here.

        Returns:
            ``[..., out_dim]`` features, same leading dims, dtype of the factors.
        """
        return query(self, points)

    def features_at(self, coords: torch.Tensor) -> torch.Tensor:
        """Features at continuous grid indices ``[N, 3]`` (see :func:`tdfields.to_grid_coords`) -> ``[N, C]``."""
        p = self.plan_at(coords[None])
        return evaluate(p.program, p.tensors, p.coords)

    def grids(self) -> list[Grid]:
        """``[(aabb, grid_shape)]``: the one grid a query reads (see :class:`FieldLike`)."""
        return [(self.aabb, self.grid_shape)]

    def plan_at(self, coords: torch.Tensor) -> Plan:
        """The :class:`~tdfields.program.Plan` of a query at grid coordinates ``coords [1, N, 3]``.

        By default :meth:`whole_grid_program` and the coordinates unchanged. A kind may hand back tensors covering
        only the region the points touch, with the coordinates shifted to match (Six-axis composes sub-planes in
        mapping).
        """
        program, tensors = self.whole_grid_program(coords.shape[1])
        return Plan(program, tuple(tensors), coords)

    def whole_grid_program(self, num_points: int) -> tuple[Program, list[torch.Tensor]]:
        """The :class:`tdfields.program.Program` of a query of ``num_points`` points anywhere in the grid, and the
        tensors it reads (covering the whole grid).

        By default the factors themselves; a kind may substitute equivalent tensors (Six-axis composes its whole
        planes for large batches, and caches them inside :func:`tdfields.frozen`).
        """
        specs = self.factor_specs()
        names = list(specs)
        index = {name: i for i, name in enumerate(names)}
        terms = self.terms()
        program = single([specs[n].axes for n in names], [tuple(index[n] for n in t) for t in terms],
                         [specs[t[0]].width // self.channels for t in terms], self.channels)
        return program, [self.factors[n] for n in names]

    def contains(self, points: torch.Tensor) -> torch.Tensor:
        """``[..., 3]`` world points -> ``[...]`` bool mask, True inside the (closed) box."""
        return contains(self.aabb, points)

    # -- caching (see tdfields.frozen) ------------------------------------------------------------------------
    @property
    def is_frozen(self) -> bool:
        """Whether a :func:`tdfields.frozen` block holds this field (its caches may then live)."""
        return self._frozen_depth > 0

    def clear_cache(self) -> None:
        """Drop whatever the kind derived from its factors (nothing, unless the kind caches inside
        :func:`tdfields.frozen`)."""

    # -- accounting ------------------------------------------------------------------------------------------
    def num_parameters(self) -> int:
        """Number of trainable scalars: the sum of the factors' ``numel()``."""
        return sum(p.numel() for p in self.parameters())

    def parameter_breakdown(self) -> dict[str, int]:
        """Factor name -> number of scalars."""
        return {name: p.numel() for name, p in self.factors.items()}

    def closed_form_parameters(self) -> int:
        """Parameter count from the kind's formula and the grid shape alone (no tensors involved)."""
        return sum(math.prod(self.grid_shape[a] for a in spec.axes) * spec.width
                   for spec in self.factor_specs().values())

    def memory_bytes(self) -> int:
        """Bytes held by the parameters (Adam training keeps about three times this again in state and grads)."""
        return sum(p.numel() * p.element_size() for p in self.parameters())

    def spec(self) -> dict:
        """A config dict that rebuilds this field with its current box and grid (see :func:`tdfields.build`)."""
        out = {"kind": self.kind, "aabb": self.aabb.tolist(), "grid_shape": list(self.grid_shape),
               "channels": self.channels, "init_std": self.init_std}
        if self.has_rank:
            out["rank"] = self.rank
        return out

    def extra_repr(self) -> str:
        rank = f", rank={self.rank}" if self.has_rank else ""
        return (f"grid_shape={self.grid_shape}, channels={self.channels}{rank}, "
                f"params={self.num_parameters():,}, complexity={self.complexity}")
