"""Optional fused kernels behind :func:`tdfields.interpolate`, with the pure-PyTorch path as fallback and oracle.

Backends, chosen with :func:`set_backend` or the ``TDFIELDS_BACKEND`` environment variable:

* ``"auto"`` (default): the numba CPU kernel for CPU tensors when numba imports, the PyTorch reference
  otherwise (CUDA tensors, ``torch.compile`` tracing, numba missing).
* ``"torch"``: always the reference (also the only path with second derivatives).
* ``"numba"``: the CPU kernel; an error if numba is missing.

The kernel supports first derivatives only. A second derivative through it raises an error instead of
silently returning zeros; select ``"torch"`` for eikonal-style losses.
"""

from __future__ import annotations

import contextlib
import os

import torch
from torch.autograd.function import once_differentiable

BACKENDS = ("auto", "torch", "numba")
_state = {"backend": os.environ.get("TDFIELDS_BACKEND", "auto"), "numba": None}
if _state["backend"] not in BACKENDS:
    raise ValueError(f"TDFIELDS_BACKEND must be one of {BACKENDS}, got {_state['backend']!r}")

# Per-thread gradient buffers are only worth it while they are small next to the work; beyond this many
# floats per buffer the scatter runs in one chunk.
_MAX_BUFFER_FLOATS = 1 << 24


def set_backend(name: str) -> None:
    """Select the interpolation backend: ``"auto"``, ``"torch"`` or ``"numba"``."""
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
    if name == "numba" and not numba_available():
        raise RuntimeError("backend 'numba' requested but numba is not importable; pip install numba")
    _state["backend"] = name


@contextlib.contextmanager
def use_backend(name: str):
    """Context manager: select ``name`` inside the block, restore the previous backend after it."""
    previous = _state["backend"]
    set_backend(name)
    try:
        yield
    finally:
        _state["backend"] = previous


def get_backend() -> str:
    """The selected backend name."""
    return _state["backend"]


def _numba_module():
    if _state["numba"] is None:
        try:
            from tdfields.kernels import cpu_numba
        except Exception:  # ImportError, or numba failing to initialise on an odd platform
            _state["numba"] = False
        else:
            _state["numba"] = cpu_numba
    return _state["numba"] or None


def numba_available() -> bool:
    """Whether the numba CPU kernel can be used."""
    return _numba_module() is not None


def use_fused(grid: torch.Tensor, coords: torch.Tensor) -> bool:
    """Whether :func:`tdfields.interpolate` takes the fused kernel for these tensors."""
    backend = _state["backend"]
    if backend == "torch" or grid.device.type != "cpu" or coords.device.type != "cpu":
        return False
    if torch.compiler.is_compiling() or grid.dtype not in (torch.float32, torch.float64):
        return False
    if backend == "numba":
        return True
    return numba_available()


def _geometry(grid: torch.Tensor, d: int):
    import numpy as np

    sizes = np.asarray(grid.shape[:d], dtype=np.int64)
    strides = np.ones(d, dtype=np.int64)
    for a in range(d - 2, -1, -1):
        strides[a] = strides[a + 1] * sizes[a + 1]
    return sizes, strides


class _FusedInterpolate(torch.autograd.Function):
    @staticmethod
    def forward(ctx, grid, coords):
        kern = _numba_module()
        d = coords.shape[-1]
        g = grid.detach().contiguous()
        c = coords.detach().to(g.dtype).contiguous()
        flat = g.view(-1, g.shape[-1])
        out = torch.empty(c.shape[0], flat.shape[1], dtype=g.dtype)
        sizes, strides = _geometry(g, d)
        kern.forward(flat.numpy(), sizes, strides, c.numpy(), out.numpy())
        ctx.save_for_backward(g, c)
        ctx.coords_dtype = coords.dtype
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out):
        kern = _numba_module()
        g, c = ctx.saved_tensors
        want_grid, want_coords = ctx.needs_input_grad
        d = c.shape[-1]
        flat = g.view(-1, g.shape[-1])
        go = grad_out.to(g.dtype).contiguous()
        threads = kern.num_threads()
        chunks = threads if want_grid and flat.numel() * threads <= _MAX_BUFFER_FLOATS else 1
        buffers = torch.zeros((chunks, *flat.shape) if want_grid else (1, 1, flat.shape[1]), dtype=g.dtype)
        grad_coords = torch.zeros_like(c) if want_coords else torch.zeros(1, d, dtype=g.dtype)
        sizes, strides = _geometry(g, d)
        kern.backward(flat.numpy(), sizes, strides, c.numpy(), go.numpy(), buffers.numpy(), grad_coords.numpy(),
                      want_grid, want_coords)
        grad_grid = buffers.sum(0).view_as(g) if want_grid else None
        return grad_grid, grad_coords.to(ctx.coords_dtype) if want_coords else None


def fused_interpolate(grid: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Fused equivalent of :func:`tdfields.interpolation.interpolate_reference` (first derivatives only)."""
    if _numba_module() is None:
        raise RuntimeError("the fused CPU kernel needs numba; pip install numba, or set_backend('torch')")
    return _FusedInterpolate.apply(grid, coords)
