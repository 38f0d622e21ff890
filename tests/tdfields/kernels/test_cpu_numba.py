"""The fused CPU kernel against the pure-PyTorch reference, under fixed seeds."""

import pytest
import torch

import tdfields
from tdfields import kernels
from tdfields.interpolation import interpolate_reference

pytestmark = pytest.mark.skipif(not kernels.numba_available(), reason="numba not installed")


@pytest.mark.parametrize("shape", [(37,), (13, 9), (5, 6, 7)])
@pytest.mark.parametrize("dtype, tol", [(torch.float64, {}), (torch.float32, {"rtol": 1e-5, "atol": 1e-5})])
@pytest.mark.parametrize("wants", [(True, True), (True, False), (False, True)])
def test_values_and_gradients_match_reference(shape, dtype, tol, wants):
    torch.manual_seed(0)
    d = len(shape)
    grid = torch.randn(*shape, 6, dtype=dtype, requires_grad=wants[0])
    coords = torch.rand(300, d, dtype=dtype) * (torch.tensor(shape, dtype=dtype) - 1)
    coords[0] = 0  # both faces of the box, where the lower corner index is clamped
    coords[1] = torch.tensor(shape, dtype=dtype) - 1
    coords.requires_grad_(wants[1])
    ref = interpolate_reference(grid, coords)
    fused = kernels.fused_interpolate(grid, coords)
    torch.testing.assert_close(fused, ref, **tol)
    grad_out = torch.randn_like(ref)
    inputs = [t for t, w in zip((grid, coords), wants) if w]
    for a, b in zip(torch.autograd.grad(ref, inputs, grad_out), torch.autograd.grad(fused, inputs, grad_out)):
        torch.testing.assert_close(b, a, **tol)


def test_large_grid_uses_single_buffer_and_stays_exact(monkeypatch):
    monkeypatch.setattr(kernels, "_MAX_BUFFER_FLOATS", 10)
    grid = torch.randn(20, 20, 4, dtype=torch.float64, requires_grad=True)
    coords = torch.rand(500, 2, dtype=torch.float64) * 19
    (ga,) = torch.autograd.grad(interpolate_reference(grid, coords).sum(), grid)
    (gb,) = torch.autograd.grad(kernels.fused_interpolate(grid, coords).sum(), grid)
    torch.testing.assert_close(gb, ga)


@pytest.mark.parametrize("kind", sorted(tdfields.KINDS))
def test_whole_fields_match_between_backends(kind):
    torch.manual_seed(0)
    spec = {"kind": kind, "aabb": [[0, 1], [0, 2], [0, 1]], "cell_size": 0.1, "channels": 8}
    if tdfields.KINDS[kind].has_rank:
        spec["rank"] = 4
    f = tdfields.build(spec)
    x = (torch.rand(2000, 3) * torch.tensor([1.2, 2.4, 1.2]) - 0.1).requires_grad_(True)
    out = {}
    for backend in ("torch", "numba"):
        with kernels.use_backend(backend):
            y = f(x)
            grads = torch.autograd.grad(y.square().sum(), [x, *f.parameters()])
        out[backend] = (y, grads)
    torch.testing.assert_close(out["numba"][0], out["torch"][0], rtol=1e-5, atol=1e-6)
    for a, b in zip(out["torch"][1], out["numba"][1]):
        torch.testing.assert_close(b, a, rtol=1e-4, atol=1e-5)


def test_second_derivative_raises_instead_of_silent_zero():
    f = tdfields.CP([[0, 1]] * 3, cell_size=0.25, channels=2, rank=2)
    x = torch.rand(10, 3, requires_grad=True)
    with kernels.use_backend("numba"):
        (g,) = torch.autograd.grad(f(x).sum(), x, create_graph=True)
        with pytest.raises(RuntimeError, match="differentiate twice"):
            g.sum().backward()


def test_backend_selection_errors():
    with pytest.raises(ValueError, match="backend"):
        kernels.set_backend("cuda-magic")
    assert kernels.get_backend() in kernels.BACKENDS
    with kernels.use_backend("torch"):
        assert not kernels.use_fused(torch.zeros(2, 1), torch.zeros(1, 1))
