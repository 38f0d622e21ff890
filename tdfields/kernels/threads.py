"""The CPU threads the fused kernels split a batch over: a pool of workers and the rule for how many to use.

The numba kernels release the GIL, so ordinary Python threads run them in parallel. The pool follows torch's
intra-op thread count (``torch.set_num_threads``) instead of keeping a setting of its own.
"""

from __future__ import annotations

import concurrent.futures
from typing import Callable, Sequence

import torch

# below this many points per thread, handing work to another thread costs more than it saves
_MIN_POINTS_PER_THREAD = 4096
_pool: dict = {"executor": None, "size": 0}


def num_threads() -> int:
    """Threads the fused CPU kernels use: torch's intra-op thread count (``torch.set_num_threads``)."""
    return max(1, torch.get_num_threads())


def parts_for(n_points: int) -> int:
    """How many slices to cut a batch of ``n_points`` into: one per thread, none under the per-thread minimum."""
    return max(1, min(num_threads(), n_points // _MIN_POINTS_PER_THREAD))


def split(n_points: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous ``(start, stop)`` ranges covering ``[0, n_points)`` (one empty range for none)."""
    if n_points <= 0:
        return [(0, 0)]
    step = -(-n_points // parts)
    return [(a, min(n_points, a + step)) for a in range(0, n_points, step)]


def run(jobs: Sequence[Callable[[], None]]) -> None:
    """Run zero-argument callables, the first on this thread and the rest on the pool (kernels release the GIL)."""
    if len(jobs) == 1:
        jobs[0]()
        return
    if _pool["size"] < len(jobs) - 1:
        if _pool["executor"] is not None:
            _pool["executor"].shutdown(wait=False)
        _pool["executor"] = concurrent.futures.ThreadPoolExecutor(len(jobs) - 1, thread_name_prefix="tdfields")
        _pool["size"] = len(jobs) - 1
    futures = [_pool["executor"].submit(job) for job in jobs[1:]]
    jobs[0]()
    for fut in futures:
        fut.result()
