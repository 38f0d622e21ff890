"""The Triton kernel against the reference: compiled on a CUDA device when TRITON_INTERPRET=0 and one is
present, else in Triton's interpreter on CPU tensors (tests/conftest.py sets TRITON_INTERPRET=1 without a GPU)."""

import os

import pytest
import torch

import tdfields
from tdfields import kernels

pytest.importorskip("triton")
INTERPRET = os.environ.get("TRITON_INTERPRET", "") not in ("", "0")
DEVICE = "cpu" if INTERPRET else "cuda"
pytestmark = pytest.mark.skipif(not INTERPRET and not torch.cuda.is_available(),
                                reason="Triton needs a CUDA device, or TRITON_INTERPRET=1 before triton is imported")

BOX = [[-1.0, 1.0], [-0.5, 1.0], [-1.0, 0.5]]
LEVEL_KW = {"cp": {"rank": 2}, "triplane": {}, "six_axis": {"rank": 3, "strategy": "factors"},
            "vector_matrix": {"rank": 2}, "dense_grid": {}}


def _field(kinds, channels=5, dtype=torch.float64):
    torch.manual_seed(0)
    levels = [{"kind": k, "aabb": BOX, "cell_size": cell, "channels": channels, **LEVEL_KW[k]}
              for k, cell in zip(kinds, (0.5, 0.25))]
    return tdfields.build({"kind": "multires", "levels": levels}).to(device=DEVICE, dtype=dtype)


def _points(n=300, dtype=torch.float64):
    torch.manual_seed(1)
    return (torch.rand(n, 3, dtype=dtype) * 2.4 - 1.2).to(DEVICE)  # some outside the box: clamped


@pytest.mark.parametrize("kind", sorted(LEVEL_KW))
def test_values_and_all_gradients_match_reference(kind):
    f = _field([kind, kind])
    x = _points().requires_grad_()
    res = []
    for backend in ("triton", "torch"):
        with kernels.use_backend(backend):
            y = f(x)
            res.append((y, torch.autograd.grad(y.square().sum(), [x, *f.parameters()])))
    torch.testing.assert_close(res[0][0], res[1][0])
    for a, b in zip(res[0][1], res[1][1]):
        torch.testing.assert_close(a, b)


@pytest.mark.parametrize("wants", [(True, False), (False, True)])
def test_mixed_stack_float32_and_partial_gradients(wants):
    """CP + Six-axis levels in one program, float32, only the point or only the factor gradients."""
    f = _field(["cp", "six_axis"], channels=32, dtype=torch.float32)
    x = _points(dtype=torch.float32).requires_grad_(wants[0])
    for p in f.parameters():
        p.requires_grad_(wants[1])
    inputs = [x] if wants[0] else list(f.parameters())
    res = []
    for backend in ("triton", "torch"):
        with kernels.use_backend(backend):
            y = f(x)
            res.append((y, torch.autograd.grad(y.square().sum(), inputs)))
    torch.testing.assert_close(res[0][0], res[1][0], rtol=1e-5, atol=1e-6)
    for a, b in zip(res[0][1], res[1][1]):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_empty_batch_and_second_derivative_guard():
    f = _field(["cp", "cp"])
    with kernels.use_backend("triton"):
        e = torch.zeros(0, 3, dtype=torch.float64, device=DEVICE, requires_grad=True)
        f(e).sum().backward()
        assert e.grad.shape == (0, 3)
        x = _points(10).requires_grad_()
        (g,) = torch.autograd.grad(f(x).square().sum(), x, create_graph=True)
        with pytest.raises(RuntimeError, match="cannot differentiate twice"):
            g.sum().backward()


@pytest.mark.skipif(not INTERPRET, reason="about CPU tensors in the interpreter")
def test_cpu_tensors_take_it_only_when_interpreting(monkeypatch):
    t = torch.zeros(3)
    with kernels.use_backend("triton"):
        assert kernels.use_triton(t)
        monkeypatch.setenv("TRITON_INTERPRET", "0")
        assert not kernels.use_triton(t)
        assert kernels.use_fused(t)  # CPU tensors fall back to the numba kernel
    assert not kernels.use_triton(t)  # other backends never pick it
