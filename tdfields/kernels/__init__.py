"""Optional fused kernels behind :mod:`tdfields.ops`, with the pure-PyTorch path as fallback and oracle.

The kernel evaluates a whole :class:`tdfields.program.Program` (all factors, products and rank sums of one or
several fields) in one pass per point. It supports first derivatives only: a second derivative through it
raises an error instead of silently returning zeros; select ``"torch"`` for eikonal-style losses.

This module is the package's face; the parts live by responsibility:

* :mod:`~tdfields.kernels.backend`: the selected backend (:func:`set_backend`, ``TDFIELDS_BACKEND``: ``"auto"``,
  ``"torch"``, ``"numba"``, ``"triton"``), which libraries import, and :func:`use_fused` / :func:`use_triton`, the
  per-call decision.
* :mod:`~tdfields.kernels.threads`: the worker threads a CPU batch is split over (:func:`num_threads`).
* :mod:`~tdfields.kernels.fused`: the autograd Functions and their entry points (:func:`fused_evaluate`,
  :func:`triton_evaluate`, :func:`fused_grid_coords`, :func:`fused_interpolate`, :func:`compose_plane`);
  :mod:`~tdfields.kernels.second_order` makes a second derivative through them fail loudly.
* :mod:`~tdfields.kernels.codegen` / :mod:`~tdfields.kernels.triton_codegen` write the kernels' source,
  :mod:`~tdfields.kernels.generated` compiles and caches it; :mod:`~tdfields.kernels.coords` holds the numba
  grid-coordinate kernels, :mod:`~tdfields.kernels.cpu_numba` and :mod:`~tdfields.kernels.gpu_triton` are
  imported only when numba / Triton is.
"""

from tdfields.kernels.backend import (
    BACKENDS,
    get_backend,
    numba_available,
    set_backend,
    triton_available,
    use_backend,
    use_fused,
    use_triton,
)
from tdfields.kernels.fused import (
    compose_plane,
    fused_evaluate,
    fused_grid_coords,
    fused_interpolate,
    triton_evaluate,
)
from tdfields.kernels.threads import num_threads

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
    "compose_plane",
]
