import platform
import subprocess
import sys

import pytest
import torch

from slam.engine import runtime

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


def test_keep_freed_memory_applies_on_glibc_only(monkeypatch):
    monkeypatch.setitem(runtime._state, "heap_kept", False)
    if GLIBC:
        assert runtime.keep_freed_memory() is True
        assert runtime.keep_freed_memory() is True  # idempotent
        big = torch.ones(12_000_000)  # 48 MB: above glibc's largest mmap threshold, now served by the heap
        assert float(big.sum()) == 12_000_000
    monkeypatch.setitem(runtime._state, "heap_kept", False)
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    assert runtime.keep_freed_memory() is False


# a fresh process (the setting is process-wide) mallocs, fills and frees a 40 MiB block 10 times and prints the
# share of its pages that faulted in again per round: 1.0 means every round paid for fresh pages
_REFAULTS = r"""
import ctypes, ctypes.util, resource, sys
from slam.engine import runtime
if sys.argv[1] == "keep":
    assert runtime.keep_freed_memory()
libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.malloc.restype, libc.free.argtypes = ctypes.c_void_p, [ctypes.c_void_p]
libc.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
n = 40 << 20
def once():
    p = libc.malloc(n)
    libc.memset(p, 1, n)
    libc.free(p)
once()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    once()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 10 / (n / 4096))
"""


def _refaulted_share(mode: str) -> float:
    out = subprocess.run([sys.executable, "-c", _REFAULTS, mode], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not GLIBC, reason="glibc's mallopt")
def test_keep_freed_memory_reuses_a_freed_big_block_instead_of_faulting_fresh_pages():
    # the trim threshold once reached mallopt as a Python int cut to a C int (1 << 40 -> 0, "trim on every free"),
    # and every round faulted in all its pages again, as glibc's default mmap does
    assert _refaulted_share("default") > 0.9
    assert _refaulted_share("keep") < 0.05


def test_set_threads_zero_keeps_the_default():
    before = torch.get_num_threads()
    runtime.set_threads(0)
    assert torch.get_num_threads() == before
    runtime.set_threads(1)
    try:
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)



def test_release_freed_memory_runs_on_glibc_only_and_leaves_live_tensors_intact(monkeypatch):
    # what it saves is measured by benchmarks/memory_rss.py (settings after vs no_trim), not here: whether glibc
    # keeps a freed block depends on where the heap could grow in this process
    live = [torch.full((1000,), float(i)) for i in range(100)]
    gone = [torch.ones(1_000_000) for _ in range(20)]
    del gone
    assert runtime.release_freed_memory() is GLIBC
    assert all(float(t.sum()) == 1000.0 * i for i, t in enumerate(live))
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    assert runtime.release_freed_memory() is False
