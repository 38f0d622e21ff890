import platform

import torch

from slam.engine import runtime


def test_keep_freed_memory_applies_on_glibc_only(monkeypatch):
    monkeypatch.setitem(runtime._state, "heap_kept", False)
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert runtime.keep_freed_memory() is True
        assert runtime.keep_freed_memory() is True  # idempotent
        big = torch.ones(12_000_000)  # 48 MB: above glibc's largest mmap threshold, now served by the heap
        assert float(big.sum()) == 12_000_000
    monkeypatch.setitem(runtime._state, "heap_kept", False)
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    assert runtime.keep_freed_memory() is False


def test_set_threads_zero_keeps_the_default():
    before = torch.get_num_threads()
    runtime.set_threads(0)
    assert torch.get_num_threads() == before
    runtime.set_threads(1)
    try:
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
