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



def test_release_freed_memory_runs_on_glibc_only_and_leaves_live_tensors_intact(monkeypatch):
    # what it saves is measured by benchmarks/memory_rss.py (settings after vs no_trim), not here: whether glibc
    # keeps a freed block depends on where the heap could grow in this process
    live = [torch.full((1000,), float(i)) for i in range(100)]
    gone = [torch.ones(1_000_000) for _ in range(20)]
    del gone
    on_glibc = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"
    assert runtime.release_freed_memory() is on_glibc
    assert all(float(t.sum()) == 1000.0 * i for i, t in enumerate(live))
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    assert runtime.release_freed_memory() is False
