import contextlib

import pytest
import torch

from tdfields.kernels import threads


@pytest.fixture
def three_threads(monkeypatch):
    """A context manager: inside it, the numba kernels split batches over 3 threads from 1,000 points a thread
    (the split a large batch takes on a multi-core machine, at test sizes)."""

    @contextlib.contextmanager
    def block():
        monkeypatch.setattr(threads, "_MIN_POINTS_PER_THREAD", 1000)
        previous = torch.get_num_threads()
        torch.set_num_threads(3)
        try:
            yield
        finally:
            torch.set_num_threads(previous)

    return block
