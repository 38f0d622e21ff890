"""Process-wide runtime settings a SLAM run applies once (CPU threads, the C allocator's treatment of big
tensors) and what it records of the machine (:func:`cpu_name`). All are global to the process, so they live here
and not in the scene or the fields.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import platform
from pathlib import Path

import torch

log = logging.getLogger(__name__)

# glibc mallopt parameter numbers (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_state = {"heap_kept": False}


def set_threads(n: int) -> None:
    """Use ``n`` CPU threads for torch and tdfields' fused kernels, which follow torch's count (0: defaults).

    On a small shared CPU one thread per process is usually fastest: OpenMP's spinning worker threads otherwise
    fight with other work over the same cores.
    """
    if n > 0:
        torch.set_num_threads(n)


def keep_freed_memory() -> bool:
    """Serve large tensors from glibc's heap and keep freed memory in the process (Linux/glibc only).

    glibc hands every allocation above 32 MiB (its largest mmap threshold) to a fresh ``mmap``, and returns it on
    free. A mapping iteration at room scale allocates several such tensors (``[160k, 64]`` float32 features
    and their gradients are 41 MB each), and each first touch of the fresh pages faults: 17 ms per 41 MB tensor
    measured here, against 1 ms to fill a reused one. With mmap disabled and trimming off, freed blocks are
    reused instead. The cost: the process keeps its peak heap size until it exits (glibc still maps
    allocations of other threads' arenas that do not fit a heap).

    Returns:
        True when the setting was applied (now or earlier), False where it does not apply (not glibc).
    """
    if _state["heap_kept"]:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        ok = libc.mallopt(_M_MMAP_MAX, 0) == 1 and libc.mallopt(_M_TRIM_THRESHOLD, 1 << 40) == 1
    except (OSError, AttributeError) as exc:  # no libc to load, or no mallopt in it
        log.debug("keep_freed_memory: %s", exc)
        return False
    _state["heap_kept"] = ok
    return ok


def cpu_name() -> str:
    """The CPU model (``/proc/cpuinfo``'s model name where it exists), for stamping results."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
