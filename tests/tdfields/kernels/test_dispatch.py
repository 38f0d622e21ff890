"""Backend choice (tdfields.kernels.dispatch): the setting, its errors, and a missing library."""

import pytest
import torch

from tdfields import kernels
from tdfields.kernels import dispatch


def test_backend_selection_errors():
    with pytest.raises(ValueError, match="backend"):
        kernels.set_backend("cuda-magic")
    assert kernels.get_backend() in kernels.BACKENDS
    with kernels.use_backend("torch"):
        assert not kernels.use_fused(torch.zeros(2, 1), torch.zeros(1, 1))


def test_missing_triton_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(dispatch._state, "triton", False)
    with pytest.raises(RuntimeError, match="pip install triton"):
        kernels.set_backend("triton")
