"""The Triton (GPU) backend: :mod:`~tdfields.kernels.triton.source` writes a kernel per program and
:mod:`~tdfields.kernels.triton.autograd` holds its autograd Function and entry point (``triton_evaluate``).

Only the generated code and the kernel launch import triton itself; this package and its source writer do not.
"""
