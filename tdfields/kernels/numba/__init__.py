"""The numba (CPU) backend: :mod:`~tdfields.kernels.numba.source` writes a kernel per program (and the Six-axis
plane composition), :mod:`~tdfields.kernels.numba.coords` holds the hand-written world-to-grid kernels,
:mod:`~tdfields.kernels.numba.cells` marks the cells of a plane a query reads, and
:mod:`~tdfields.kernels.numba.autograd` the autograd Functions with their entry points (``fused_evaluate``,
``fused_compose_plane``, ``fused_grid_coords``, ``fused_interpolate``).

Only ``coords``, ``cells`` and the generated code import numba itself; this package and its source writer do not.
"""
