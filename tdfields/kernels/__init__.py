"""Optional fused kernels behind :mod:`tdfields.ops`, with the pure-PyTorch path as fallback and oracle.

The kernel evaluates a whole :class:`tdfields.program.Program` (all factors, products and rank sums of one or
several fields) in one pass per point. It supports first derivatives only: a second derivative through it
raises an error instead of silently returning zeros; select ``"torch"`` for eikonal-style losses.

This module is the package's face; the parts live by backend and role:

* :mod:`~tdfields.kernels.dispatch`: backend choice. The selected backend (:func:`set_backend`,
  ``TDFIELDS_BACKEND``: ``"auto"``, ``"torch"``, ``"numba"``, ``"triton"``), which libraries import, and
  :func:`use_fused` (numba) / :func:`use_triton`, the per-call decision :mod:`tdfields.ops` asks for.
* :mod:`~tdfields.kernels.numba`: the CPU backend. ``numba.source`` writes a kernel per program, ``numba.coords``
  holds the world-to-grid kernels, ``numba.cells`` marks the plane cells a query reads, ``numba.autograd`` the
  autograd Functions and entry points
  (:func:`fused_evaluate`, :func:`fused_compose_plane`, :func:`fused_grid_coords`, :func:`fused_interpolate`).
* :mod:`~tdfields.kernels.triton`: the GPU backend. ``triton.source`` writes a kernel per program,
  ``triton.autograd`` holds its autograd Function and entry point (:func:`triton_evaluate`).
* :mod:`~tdfields.kernels.emitters`: the code-generation helpers both backends' writers share.
* :mod:`~tdfields.kernels.cache`: compiles the written source and caches it on disk and in the process.
* :mod:`~tdfields.kernels.threads`: the worker threads a CPU batch is split over (:func:`num_threads`);
  :mod:`~tdfields.kernels.second_order` makes a second derivative through any kernel fail loudly.

:func:`source` returns the kernel source written for a program, to read or print.
"""

from __future__ import annotations

from typing import Sequence

from tdfields.kernels.dispatch import (
    BACKENDS,
    get_backend,
    numba_available,
    set_backend,
    triton_available,
    use_backend,
    use_fused,
    use_triton,
)
from tdfields.kernels.numba import source as _numba_source
from tdfields.kernels.numba.autograd import (
    fused_compose_plane,
    fused_evaluate,
    fused_grid_coords,
    fused_interpolate,
)
from tdfields.kernels.threads import num_threads
from tdfields.kernels.triton import source as _triton_source
from tdfields.kernels.triton.autograd import triton_evaluate
from tdfields.program import Program

__all__ = [
    "BACKENDS",
    "set_backend",
    "use_backend",
    "get_backend",
    "numba_available",
    "triton_available",
    "use_fused",
    "use_triton",
    "num_threads",
    "fused_evaluate",
    "triton_evaluate",
    "fused_grid_coords",
    "fused_interpolate",
    "fused_compose_plane",
    "source",
]


def source(program: Program, widths: Sequence[int], *, backend: str = "numba", kind: str = "forward",
           dtype: str = "float32", want_factors: Sequence[bool] | None = None, want_coords: bool = True) -> str:
    """The Python source of the kernel generated for ``program``: the text the backend compiles (nothing is
    compiled or cached here, and neither numba nor triton is imported).

    Args:
        program: the query structure, e.g. from :meth:`tdfields.Field.whole_grid_program` or
            :func:`tdfields.plan`.
        widths: each factor tensor's last dimension (``k * C``), in program order.
        backend: ``"numba"`` (CPU) or ``"triton"`` (GPU).
        kind: ``"forward"`` or ``"backward"``.
        dtype: ``"float32"`` or ``"float64"`` (numba bakes it in; Triton kernels take it from their arguments).
        want_factors: for ``"backward"``, which factors' gradients it produces (default: all).
        want_coords: for ``"backward"``, whether it produces the coordinate gradient.

    A CP field's forward kernel: one function over a point range, the three line factors ``F0..F2`` blended at
    every point and multiplied, summed over the rank (``python -c`` this to read all of it)::

        >>> import tdfields
        >>> from tdfields import kernels
        >>> field = tdfields.CP([[0, 1], [0, 1], [0, 1]], grid_shape=(8, 8, 8), channels=4, rank=2)
        >>> program, tensors = field.whole_grid_program(num_points=1)
        >>> widths = [t.shape[-1] for t in tensors]
        >>> text = kernels.source(program, widths)
        >>> print(next(line for line in text.splitlines() if line.startswith("def ")))
        def forward(F0, F1, F2, sizes, coords, out, start, stop):
        >>> print(text.splitlines()[-1].strip())
        out[n, 0 + c] = s
        >>> "forward" in compile(text, "<CP forward>", "exec").co_names
        True

    The same program's Triton backward, both gradients::

        >>> text = kernels.source(program, widths, backend="triton", kind="backward")
        >>> print(next(line for line in text.splitlines() if line.startswith("def ")))
        def backward(F0, F1, F2, coords, grad_out, G0, G1, G2, grad_coords, N, S0_0, S1_0, S2_0, BLOCK: tl.constexpr):
    """
    widths = tuple(int(w) for w in widths)
    wanted = tuple(bool(w) for w in want_factors) if want_factors is not None else (True,) * len(widths)
    if backend not in ("numba", "triton") or kind not in ("forward", "backward"):
        raise ValueError(f"source: backend must be 'numba' or 'triton' and kind 'forward' or 'backward', "
                         f"got {backend!r}, {kind!r}")
    if len(widths) != len(program.factor_axes) or len(wanted) != len(widths):
        raise ValueError(f"source: the program has {len(program.factor_axes)} factors, got {len(widths)} widths "
                         f"and {len(wanted)} want_factors")
    if backend == "triton":
        if kind == "forward":
            return _triton_source.forward_source(program, widths)
        return _triton_source.backward_source(program, widths, wanted, want_coords)
    if kind == "forward":
        return _numba_source.forward_source(program, widths, dtype)
    return _numba_source.backward_source(program, widths, wanted, want_coords, dtype)
