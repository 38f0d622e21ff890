"""Code-generation helpers every backend's kernel writer shares (:mod:`tdfields.kernels.numba.source`,
:mod:`tdfields.kernels.triton.source`), and the check of what every generated query kernel assumes of its arguments
(:func:`check_inputs`).

A generated kernel names its per-point values after the factor ``f`` and its ``a``-th axis: the lower corner
index ``i{f}_{a}``, the fraction ``t{f}_{a}``, the base row ``b{f}``, the ``2**d`` corner rows ``r{f}_{k}``, their
weights ``w{f}_{k}`` and the weights' derivatives ``dw{f}_{k}_{a}``. The helpers here write those lines from a
backend's templates, so both backends blend the corners the same way.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from tdfields.program import Program

if TYPE_CHECKING:
    import torch

#: ``[(offset, C, [(term, rank), ...]), ...]``: the terms that add into one output range, and its channel count
Groups = list[tuple[int, int, list[tuple[tuple[int, ...], int]]]]


def output_groups(program: Program, widths: tuple[int, ...]) -> Groups:
    """Terms grouped by output offset: ``[(offset, C, [(term, rank), ...]), ...]`` in program order."""
    groups: dict[int, tuple[int, list]] = {}
    for term, k, off in zip(program.terms, program.ranks, program.offsets):
        C = widths[term[0]] // k
        if off in groups and groups[off][0] != C:
            raise ValueError(f"terms writing at offset {off} disagree on their channel count")
        groups.setdefault(off, (C, []))[1].append((term, k))
    return [(off, C, terms) for off, (C, terms) in groups.items()]


def corner_lines(f: int, sizes: list[str], one: str, with_derivatives: bool, constant: str = "{value}") -> list[str]:
    """From the lower indices ``i{f}_{a}`` and fractions ``t{f}_{a}`` already in scope: the base row ``b{f}``, the
    ``2**d`` corner rows ``r{f}_{k}`` (axis 0 the most significant bit of ``k``), their weights ``w{f}_{k}`` and,
    if asked, the weights' derivatives ``dw{f}_{k}_{a}`` along each axis.

    Args:
        sizes: the source expression of the factor's size along each of its axes.
        one: the source of the literal 1 in the kernel's dtype.
        constant: template (``{value}``, ``{f}``) of a derivative that is a bare constant (a line factor's +-1),
            for kernels that need it shaped like the other per-point values.
    """
    nd = len(sizes)
    lines = []
    # row-major strides of the factor's spatial dims, in rows of the [rows, width] view
    strides = [" * ".join(sizes[a + 1:]) or "1" for a in range(nd)]
    base = " + ".join(f"i{f}_{a} * {strides[a]}" if strides[a] != "1" else f"i{f}_{a}" for a in range(nd))
    lines.append(f"b{f} = {base}")
    for k in range(1 << nd):
        bits = [(k >> (nd - 1 - a)) & 1 for a in range(nd)]
        offset = " + ".join(strides[a] for a in range(nd) if bits[a])
        lines.append(f"r{f}_{k} = b{f}" + (f" + {offset}" if offset else ""))
        factors = [f"t{f}_{a}" if bits[a] else f"({one} - t{f}_{a})" for a in range(nd)]
        lines.append(f"w{f}_{k} = " + " * ".join(factors))
        if with_derivatives:
            for a in range(nd):
                parts = [(one if bits[b] else f"-{one}") if b == a else factors[b] for b in range(nd)]
                value = " * ".join(parts) if nd > 1 else constant.format(f=f, value=parts[0])
                lines.append(f"dw{f}_{k}_{a} = {value}")
    return lines


def corner_setup(program: Program, with_derivatives: bool, index: Sequence[str], size: str, one: str,
                 constant: str = "{value}") -> list[str]:
    """Every factor's corner set-up in program order: the backend's ``index`` lines per axis (templates in
    ``{f}``, ``{a}``, ``{axis}``, ``{level}`` that bring ``i{f}_{a}`` and ``t{f}_{a}`` into scope), then
    :func:`corner_lines` with the factor's sizes (``size``, a template in ``{f}`` and ``{a}``)."""
    lines = []
    for f, (axes, level) in enumerate(zip(program.factor_axes, program.factor_level)):
        for a, axis in enumerate(axes):
            lines += [line.format(f=f, a=a, axis=axis, level=level) for line in index]
        lines += corner_lines(f, [size.format(f=f, a=a) for a in range(len(axes))], one, with_derivatives, constant)
    return lines


def coordinate_axes(program: Program) -> list[tuple[int, int]]:
    """The ``(level, axis)`` pairs the program's factors read, sorted: one coordinate-gradient sum ``d_{lv}_{a}``
    each in a backward kernel."""
    return sorted({(level, a) for axes, level in zip(program.factor_axes, program.factor_level) for a in axes})


def active_factors(term: tuple[int, ...], want_factors: tuple[bool, ...], want_coords: bool) -> list[int]:
    """Positions in ``term`` of the factors a backward kernel differentiates: those whose gradient is wanted, or
    all of them when the coordinate gradient is."""
    return [i for i, f in enumerate(term) if want_factors[f] or want_coords]


def check_inputs(program: Program, factors: Sequence[torch.Tensor], coords: torch.Tensor, kernel: str) -> None:
    """What every generated query kernel assumes: the program's factors, ``[levels, N, 3]`` coordinates, at most
    3 factors a term."""
    program.check(factors)
    if coords.dim() != 3 or coords.shape[0] != program.num_levels or coords.shape[2] != 3:
        raise ValueError(f"coords must be [{program.num_levels}, N, 3], got {tuple(coords.shape)}")
    if max(len(t) for t in program.terms) > 3:
        raise ValueError(f"the {kernel} kernel multiplies at most 3 factors per term; use set_backend('torch')")

