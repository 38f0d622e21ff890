"""Process-wide runtime settings a SLAM run applies (CPU threads, the C allocator's treatment of big tensors and
the return of its free pages) and what it records of the machine (:func:`cpu_name`, :func:`float_fingerprint`).
All are global to the process, so they live here and not in the scene or the fields.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import hashlib
import logging
import platform
from pathlib import Path

import torch

log = logging.getLogger(__name__)

# glibc mallopt parameter numbers (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
# mallopt takes a C int: a Python int passed without a ctypes type is cut to its low 32 bits (1 << 40 became 0,
# which means "trim on every free", the opposite of what keep_freed_memory asks for)
_NEVER_TRIM = ctypes.c_int(2**31 - 1)
_state = {"heap_kept": False}


def _glibc() -> bool:
    """Whether this process runs on Linux with glibc, the only C library whose heap these settings reach."""
    return platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


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
    allocations of other threads' arenas that do not fit a heap). A warm ``tum/fr1_rpy-cpu-fast`` mapping call on
    the mapper's thread faults no page in (about 16,000 while the threshold reached glibc as 0;
    ``benchmarks/call_faults.py`` at f5975fa, since retired).

    Returns:
        True when the setting was applied (now or earlier), False where it does not apply (not glibc).
    """
    if _state["heap_kept"]:
        return True
    if not _glibc():
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        ok = libc.mallopt(_M_MMAP_MAX, 0) == 1 and libc.mallopt(_M_TRIM_THRESHOLD, _NEVER_TRIM) == 1
    except (OSError, AttributeError) as exc:  # no libc to load, or no mallopt in it
        log.debug("keep_freed_memory: %s", exc)
        return False
    _state["heap_kept"] = ok
    return ok


def release_freed_memory() -> bool:
    """Hand the C heap's free pages back to the operating system (glibc's ``malloc_trim(0)``; Linux/glibc only).

    Freed memory that glibc keeps is reused, but not all of it can be: the mapping thread's arena fragments as
    keyframes, window images and an iteration's temporaries of varying sizes come and go, and its resident size
    crept up by 0.7-3.6 MiB a frame at ``tum/fr1_rpy-cpu`` although the run's live tensors stayed flat
    (``benchmarks/memory_rss.py``; docs/results.md, "Memory over a long run"). Trimming every few frames
    bounds it; the pages a later call needs again fault back in (about 17 ms per 41 MB, once per trim).

    Returns:
        True when the trim ran, False where it does not apply (not glibc).
    """
    if not _glibc():
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim(0)
    except (OSError, AttributeError) as exc:
        log.debug("release_freed_memory: %s", exc)
        return False
    return True


def cpu_name() -> str:
    """The CPU model (``/proc/cpuinfo``'s model name where it exists), for stamping results."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


@functools.cache
def float_fingerprint() -> str:
    """16 hex digits that differ between machines whose float32 arithmetic rounds differently, for stamping seeded
    runs: a seed repeats a run exactly only where this agrees (docs/slam.md, "Determinism").

    The sha256 of torch's CPU capability (the instruction set ATen's own kernels were dispatched for: ``AVX512``,
    ``AVX2``, ...), of a fixed matrix product (through ``matmul`` and through ``linear``, the decoders' path) and of
    tanh / exp / sigmoid over its result, at one torch thread (the runs' count): BLAS and vector kernels chosen for
    the CPU's instruction set are where two machines' results part. The capability is in it because the products
    alone did not see it: one machine run with ``ATEN_CPU_CAPABILITY=avx2`` and with its native AVX512 gave the same
    products and different trajectories (docs/slam.md, "Determinism", where runs are paired by
    machine). It does not see a difference in numba's code generation alone. Computed once per process (it sets
    torch's thread count for a moment, so :class:`slam.engine.system.SLAM` takes it before any worker thread runs).
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        i = torch.arange(256 * 64, dtype=torch.float32)
        a = torch.sin(0.37 * i).reshape(256, 64)
        b = torch.cos(0.11 * i[: 64 * 48]).reshape(64, 48)
        y = a @ b
        parts = (y, torch.tanh(y), torch.exp(-y.abs()), torch.sigmoid(y), torch.nn.functional.linear(a, b.T))
        capability = torch.backends.cpu.get_cpu_capability().encode()
        digest = hashlib.sha256(capability + b"".join(t.contiguous().numpy().tobytes() for t in parts)).hexdigest()
    finally:
        torch.set_num_threads(threads)
    return digest[:16]
