"""Backend choice: which kernel a query may run, from the selected backend and whether numba and Triton import on
this machine. :mod:`tdfields.ops` asks :func:`use_triton` / :func:`use_fused` at every call.

Backends, chosen with :func:`set_backend` or the ``TDFIELDS_BACKEND`` environment variable:

* ``"auto"`` (default): the numba CPU kernel for CPU tensors when numba imports, the PyTorch reference
  otherwise (CUDA tensors, ``torch.compile`` tracing, numba missing).
* ``"torch"``: always the reference (also the only path with second derivatives).
* ``"numba"``: the CPU kernel; an error if numba is missing.
* ``"triton"``: the Triton kernel for CUDA tensors (opt-in: checked against the reference in Triton's
  interpreter, not yet timed or compiled on a GPU here); an error if triton is missing. CPU tensors take it only
  under ``TRITON_INTERPRET=1`` (the tests), and the numba kernel otherwise.

The setting is process-wide: one dict, read by :func:`use_fused` and :func:`use_triton` at every call.
"""

from __future__ import annotations

import contextlib
import importlib
import os
from types import ModuleType

import torch

BACKENDS = ("auto", "torch", "numba", "triton")
_state = {"backend": os.environ.get("TDFIELDS_BACKEND", "auto"), "numba": None, "triton": None}
if _state["backend"] not in BACKENDS:
    raise ValueError(f"TDFIELDS_BACKEND must be one of {BACKENDS}, got {_state['backend']!r}")


def set_backend(name: str) -> None:
    """Select the backend: ``"auto"``, ``"torch"``, ``"numba"`` or ``"triton"`` (see the module docstring).

    Raises:
        ValueError: an unknown name. RuntimeError: ``"numba"`` or ``"triton"`` when that library does not import.
    """
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
    if name == "numba" and not numba_available():
        raise RuntimeError("backend 'numba' requested but numba is not importable; pip install numba")
    if name == "triton" and not triton_available():
        raise RuntimeError("backend 'triton' requested but triton is not importable; pip install triton")
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


def _optional(name: str) -> ModuleType | None:
    """The library ``name`` (``"numba"``, ``"triton"``) if it imports here, else None (tried once, remembered in
    ``_state[name]``). Its import is the check that the backend's kernels can run on this machine."""
    if _state[name] is None:
        try:
            _state[name] = importlib.import_module(name)
        except Exception:  # ImportError, or the library failing to initialise on an odd platform
            _state[name] = False
    return _state[name] or None


def numba_available() -> bool:
    """Whether the numba CPU kernel can be used (``import numba`` works)."""
    return _optional("numba") is not None


def triton_available() -> bool:
    """Whether the Triton kernel can be used (``import triton`` works)."""
    return _optional("triton") is not None


def _interpreting() -> bool:
    return os.environ.get("TRITON_INTERPRET", "") not in ("", "0")


def use_triton(*tensors: torch.Tensor) -> bool:
    """Whether the Triton kernel runs for these tensors: backend ``"triton"``, all float32 or all float64, all on
    one CUDA device (or all on the CPU under ``TRITON_INTERPRET=1``), not under ``torch.compile`` tracing."""
    if _state["backend"] != "triton" or torch.compiler.is_compiling() or not tensors:
        return False
    dtype, device = tensors[0].dtype, tensors[0].device
    if dtype not in (torch.float32, torch.float64):
        return False
    if device.type != "cuda" and not (device.type == "cpu" and _interpreting()):
        return False
    return all(t.dtype == dtype and t.device == device for t in tensors) and triton_available()


def use_fused(*tensors: torch.Tensor) -> bool:
    """Whether the fused kernel runs for these tensors: all on the CPU, all float32 or all float64, not under
    ``torch.compile`` tracing, and the backend allows it."""
    backend = _state["backend"]
    if backend == "torch" or torch.compiler.is_compiling() or (backend == "triton" and _interpreting()):
        return False
    dtype = tensors[0].dtype if tensors else torch.float32
    for t in tensors:
        if t.device.type != "cpu" or t.dtype != dtype or t.dtype not in (torch.float32, torch.float64):
            return False
    if backend == "numba":
        return True
    return numba_available()  # "auto", and "triton" for CPU tensors (Triton runs on GPUs)
