"""The fused world-to-grid transform against the reference (tdfields.to_grid_coords stacked per level)."""

import pytest
import torch

import tdfields
from tdfields import kernels
from tdfields.interpolation import to_grid_coords
from tdfields.ops import grid_coords

BOXES = [torch.tensor([[-1.0, 2.0], [0.0, 1.5], [-0.5, 0.7]]), torch.tensor([[-1.2, 2.2], [-0.1, 1.5], [-0.5, 0.9]])]
SHAPES = [(13, 7, 6), (101, 51, 41)]


def _points(dtype, n=4000):
    torch.manual_seed(0)
    p = torch.rand(n, 3, dtype=dtype) * 4 - 1.5  # about half outside the boxes (clamped)
    p[0] = torch.tensor([-1.0, 0.0, -0.5])  # on the lower faces of level 0: ties in the clamp
    p[1] = torch.tensor([2.0, 1.5, 0.7])  # on its upper faces
    return p


def _reference(p):
    return torch.stack([to_grid_coords(p, b, s) for b, s in zip(BOXES, SHAPES)])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_values_bitwise_and_gradients_match_reference(dtype):
    p = _points(dtype).requires_grad_()
    with kernels.use_backend("numba"):
        fused = grid_coords(p, BOXES, SHAPES)
    ref = _reference(p)
    assert fused.shape == (2, p.shape[0], 3) and fused.dtype == dtype
    assert torch.equal(fused, ref)
    w = torch.randn_like(ref)
    (g_fused,) = torch.autograd.grad(fused, p, w)
    (g_ref,) = torch.autograd.grad(ref, p, w)
    torch.testing.assert_close(g_fused, g_ref, rtol=1e-6 if dtype == torch.float32 else 1e-12, atol=0)
    # the ties on the faces pass half the gradient, as torch.maximum / torch.minimum do
    assert g_fused[0].abs().sum() > 0


def test_clamped_points_have_zero_gradient_and_nan_stays_nan():
    p = torch.tensor([[5.0, 5.0, 5.0], [float("nan"), 0.5, 0.0]], requires_grad=True)
    with kernels.use_backend("numba"):
        c = grid_coords(p, BOXES[:1], SHAPES[:1])
    assert torch.equal(c[0, 0], torch.tensor([12.0, 6.0, 5.0]))
    assert torch.isnan(c[0, 1, 0]) and torch.isfinite(c[0, 1, 1:]).all()
    (g,) = torch.autograd.grad(c[:, 0].sum(), p)
    assert torch.equal(g[0], torch.zeros(3))


def test_threaded_split_matches_single_thread(three_threads):
    p = _points(torch.float64, 9000).requires_grad_()
    w = torch.randn(2, 9000, 3, dtype=torch.float64)

    def run():
        with kernels.use_backend("numba"):
            c = grid_coords(p, BOXES, SHAPES)
        return c, torch.autograd.grad(c, p, w)[0]

    base = run()
    with three_threads():
        split = run()
    assert torch.equal(split[0], base[0]) and torch.equal(split[1], base[1])


def test_second_derivative_raises_and_empty_batch_works():
    p = _points(torch.float64, 10).requires_grad_()
    with kernels.use_backend("numba"):
        c = grid_coords(p, BOXES, SHAPES)
        (g,) = torch.autograd.grad(c.square().sum(), p, create_graph=True)
        with pytest.raises(RuntimeError, match="cannot differentiate twice"):
            g.sum().backward()
        e = torch.zeros(0, 3, requires_grad=True)
        ce = grid_coords(e, BOXES, SHAPES)
        ce.sum().backward()
    assert ce.shape == (2, 0, 3) and e.grad.shape == (0, 3)


def test_fields_query_through_the_fused_transform_match_the_reference_path():
    """A whole multi-resolution query: same features and point gradients on both backends."""
    torch.manual_seed(1)
    f = tdfields.MultiResolution([tdfields.CP(BOXES[0].tolist(), grid_shape=SHAPES[0], channels=4, rank=2),
                                  tdfields.SixAxis(BOXES[1].tolist(), grid_shape=(9, 8, 7), channels=4, rank=3)])
    f = f.double()
    p = _points(torch.float64, 500).requires_grad_()
    outs = []
    for backend in ("numba", "torch"):
        with kernels.use_backend(backend):
            y = f(p)
            outs.append((y, torch.autograd.grad(y.square().sum(), p)[0]))
    torch.testing.assert_close(outs[0][0], outs[1][0])
    torch.testing.assert_close(outs[0][1], outs[1][1])
