"""What a field computes, as data: interpolated factors, summed products of them, reduced over rank.

Every kind in tdfields is the same computation with different factors::

    features[n, off_t + c] += sum_r prod_{f in term t} interp(factor_f, coords[level_f, n])[r * C_t + c]

summed over the kind's product terms ``t``. A tri-plane has three one-factor terms of rank 1, CP one
three-factor term of rank k, Six-axis three two-factor terms of rank k, VM three plane-times-line terms. A
:class:`Program` records that structure (which axes each factor spans, which coordinate set it reads, which factors
multiply, the rank and output offset of each term). Several fields' programs concatenate into one, so a
multi-resolution stack (coarse + fine) is evaluated in a single pass.

:func:`evaluate_reference` runs a program with plain PyTorch ops: the oracle (any-order derivatives,
``torch.compile``-able), as :func:`compose_plane_reference` is for the composition of a Six-axis plane.
:func:`tdfields.ops.evaluate` runs a program through a fused kernel of :mod:`tdfields.kernels` where one applies and
through the reference otherwise; this module imports neither.

A :class:`Plan` is one query made concrete: a program, the tensors it reads and the grid coordinates it reads them
at. Fields produce it (:func:`tdfields.plan`), :func:`concat_plans` joins several into one pass.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from tdfields.interpolation import interpolate_reference


@dataclass(frozen=True)
class Program:
    """The structure of a factorised field query (no tensors).

    Attributes:
        factor_axes: per factor, the grid axes it spans (subset of ``(0, 1, 2)``, in storage order).
        factor_level: per factor, which coordinate set (``coords[level]``) it is interpolated at.
        terms: per term, the indices of the factors whose interpolants multiply elementwise.
        ranks: per term, ``k``: each factor of the term is ``k * C`` wide (rank-major, channel-minor) and the
            product is summed over the ``k`` rank components.
        offsets: per term, the first output channel it adds into.
        out_dim: total output width.
    """

    factor_axes: tuple[tuple[int, ...], ...]
    factor_level: tuple[int, ...]
    terms: tuple[tuple[int, ...], ...]
    ranks: tuple[int, ...]
    offsets: tuple[int, ...]
    out_dim: int

    @property
    def num_levels(self) -> int:
        return max(self.factor_level) + 1

    def check(self, factors: Sequence[torch.Tensor]) -> None:
        """Raise ``ValueError`` if ``factors`` do not fit this program (count, dims, widths)."""
        if len(factors) != len(self.factor_axes):
            raise ValueError(f"program has {len(self.factor_axes)} factors, got {len(factors)} tensors")
        for i, (t, axes) in enumerate(zip(factors, self.factor_axes)):
            if t.dim() != len(axes) + 1:
                raise ValueError(f"factor {i} spans axes {axes} so needs {len(axes) + 1} dims, got {tuple(t.shape)}")
        for t, (term, k, off) in enumerate(zip(self.terms, self.ranks, self.offsets)):
            widths = {factors[f].shape[-1] for f in term}
            if len(widths) != 1 or next(iter(widths)) % k:
                raise ValueError(f"term {t}: factor widths {sorted(widths)} must agree and divide by rank {k}")
            if off + next(iter(widths)) // k > self.out_dim:
                raise ValueError(f"term {t} writes past out_dim {self.out_dim}")


def single(factor_axes: Sequence[Sequence[int]], terms: Sequence[Sequence[int]], ranks: Sequence[int],
           channels: int) -> Program:
    """The program of one field (coordinate set 0, every term adding into channels ``[0, channels)``)."""
    return Program(tuple(tuple(a) for a in factor_axes), (0,) * len(factor_axes), tuple(tuple(t) for t in terms),
                   tuple(ranks), (0,) * len(terms), channels)


def concat(programs: Sequence[Program]) -> Program:
    """Concatenate programs: level ``i`` reads ``coords[i]`` (one set per program) and writes after level ``i-1``.

    A program that already has several coordinate sets keeps them, shifted after the previous programs' sets.
    """
    axes, level, terms, ranks, offsets = [], [], [], [], []
    n_factors = n_levels = width = 0
    for p in programs:
        axes += p.factor_axes
        level += [n_levels + lv for lv in p.factor_level]
        terms += [tuple(n_factors + f for f in t) for t in p.terms]
        ranks += p.ranks
        offsets += [width + o for o in p.offsets]
        n_factors += len(p.factor_axes)
        n_levels += p.num_levels
        width += p.out_dim
    return Program(tuple(axes), tuple(level), tuple(terms), tuple(ranks), tuple(offsets), width)


@dataclass(frozen=True, eq=False)
class Plan:
    """What one query evaluates: ``evaluate(plan.program, plan.tensors, plan.coords)`` gives its features.

    Produced by :func:`tdfields.plan` (a field at world points) and :meth:`tdfields.Field.plan_at` (at grid
    coordinates); the tensors may be the factors themselves or equivalent ones a kind derived from them (Six-axis
    planes composed over the region the points touch, on the CPU kernels only at the cells the plan's coordinates
    read), with the coordinates shifted to match. So a plan's tensors are valid at its own coordinates only.

    Attributes:
        program: the query structure.
        tensors: one channels-last tensor per factor of ``program``, in its order.
        coords: ``[program.num_levels, N, 3]`` continuous grid indices, one set per level.
    """

    program: Program
    tensors: tuple[torch.Tensor, ...]
    coords: torch.Tensor


def concat_plans(plans: Sequence[Plan]) -> Plan:
    """One plan evaluating all of ``plans`` in a single pass: programs :func:`concat`-enated, tensors and coordinate
    sets in order (the outputs side by side, as the plans' own outputs concatenated)."""
    if len(plans) == 1:
        return plans[0]
    return Plan(concat([p.program for p in plans]), tuple(t for p in plans for t in p.tensors),
                torch.cat([p.coords for p in plans]))


def evaluate_reference(program: Program, factors: Sequence[torch.Tensor], coords: torch.Tensor) -> torch.Tensor:
    """Run ``program`` with plain PyTorch ops (the oracle for the fused kernels).

    Args:
        program: the query structure.
        factors: one channels-last tensor per factor, ``[*sizes along its axes, k * C]``.
        coords: ``[L, N, 3]`` continuous grid indices per coordinate set, clamped to each set's grid (see
            :func:`tdfields.to_grid_coords`).

    Returns:
        ``[N, out_dim]``; differentiable to any order w.r.t. ``factors`` and ``coords``.
    """
    n = coords.shape[1]
    samples = [interpolate_reference(t, coords[lv][:, list(axes)])
               for t, axes, lv in zip(factors, program.factor_axes, program.factor_level)]
    parts: list[tuple[int, torch.Tensor]] = []
    for term, k, off in zip(program.terms, program.ranks, program.offsets):
        prod = samples[term[0]]
        for f in term[1:]:
            prod = prod * samples[f]
        if k > 1:
            prod = prod.reshape(n, k, -1).sum(1)
        parts.append((off, prod))
    # terms that share an output range are summed; ranges are laid side by side in offset order
    blocks: dict[int, torch.Tensor] = {}
    for off, value in parts:
        blocks[off] = value if off not in blocks else blocks[off] + value
    ordered = [blocks[o] for o in sorted(blocks)]
    out = ordered[0] if len(ordered) == 1 else torch.cat(ordered, -1)
    if out.shape[-1] != program.out_dim:
        raise ValueError(f"program terms cover {out.shape[-1]} channels, out_dim is {program.out_dim}")
    return out


def compose_plane_reference(u: torch.Tensor, v: torch.Tensor, rank: int) -> torch.Tensor:
    """Rank-k plane from two line factors with ``torch.einsum`` (the oracle for the fused composition):
    ``u [n_a, k*C]``, ``v [n_b, k*C]`` -> ``[n_a, n_b, C]``, ``P[a, b, c] = sum_r u[a, r*C + c] v[b, r*C + c]``
    (rank-major, channel-minor factors); differentiable to any order."""
    return torch.einsum("akc,bkc->abc", u.reshape(u.shape[0], rank, -1), v.reshape(v.shape[0], rank, -1))
