"""The fused render tail against the PyTorch reference: values and gradients of the compositing and of the five
loss terms (float64 to finite differences), the ray selections the tracker and the mapper pass, NaNs, and when the
reference runs instead."""

import pytest
import torch

from slam.core import fused_render
from slam.core.losses import LossWeights, total_loss
from slam.core.rendering import camera_rays, render_rays
from tdfields import kernels

WEIGHTS = LossWeights(fs=10.0, center=200.0, tail=10.0, depth=1.0, color=5.0)  # ESLAM's tracking weights
T = 0.05


def _rays(R=120, dtype=torch.float32, seed=0, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    D = torch.rand(R, generator=g, dtype=dtype) + 1.0
    D[:10] = 0.0  # rays without depth: the colour term only
    dirs = torch.cat((torch.rand(R, 2, generator=g, dtype=dtype) - 0.5, torch.ones(R, 1, dtype=dtype)), 1)
    color = torch.rand(R, 3, generator=g, dtype=dtype)
    return D.to(device), dirs.to(device), color.to(device)


class _Scene(torch.nn.Module):
    """A wall at z = 1.5 m with texture; SDF and colour from a small learnable head, as a decoder would be."""

    def __init__(self, dtype):
        super().__init__()
        self.head = torch.nn.Linear(3, 4).to(dtype)
        self.register_buffer("aabb", torch.tensor([[-3.0, 3.0], [-3.0, 3.0], [-1.0, 5.0]], dtype=dtype))

    def sdf(self, p):
        return torch.tanh((1.5 - p[:, 2]) / T * 0.2 + 0.1 * self.head(p)[:, 0])

    def rgb(self, p):
        return torch.sigmoid(self.head(p)[:, 1:])


def _loss_and_grads(fused, cutoff, dtype, rows=None, device="cpu", R=120):
    """The loss, its parts, the gradients to the pose, beta and the head, and the render of ``R`` rays through a
    textured wall (the reference with ``fused=False``)."""
    D, dirs_cam, color = _rays(R=R, dtype=dtype, device=device)
    scene = _Scene(dtype)
    torch.manual_seed(0)
    scene.head.reset_parameters()
    scene.to(device)
    beta = torch.tensor(10.0, dtype=dtype, device=device, requires_grad=True)
    c2w = torch.eye(4, dtype=dtype, device=device).requires_grad_()
    origins, dirs = camera_rays(c2w, dirs_cam)
    gen = torch.Generator(device=device).manual_seed(3)
    out = render_rays(origins, dirs, D, scene.sdf, scene.rgb, beta, T, 12, 6, scene.aabb, True, gen, cutoff, fused)
    loss, parts = total_loss(out.sdf, out.z, out.depth, out.color, D, color, T, WEIGHTS, rows=rows, fused=fused)
    grads = torch.autograd.grad(loss, [c2w, beta, *scene.head.parameters()])
    return loss, parts, grads, out


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-6), (torch.float64, 1e-12)])
@pytest.mark.parametrize("cutoff", [0.0, 1e-3])
def test_render_and_loss_match_the_reference_to_rounding(dtype, tol, cutoff):
    rows = torch.rand(120, generator=torch.Generator().manual_seed(1)) > 0.2  # the tracker's inliers
    assert_matches_reference(_loss_and_grads(True, cutoff, dtype, rows), _loss_and_grads(False, cutoff, dtype, rows),
                             tol)


def assert_matches_reference(got, ref, tol):
    """Two :func:`_loss_and_grads` results agree: the loss and its parts to ``tol`` relative, every gradient the
    loop takes (the pose, beta, the head) and the render to ``10 tol`` of their largest value."""
    (loss, parts, grads, out), (ref_loss, ref_parts, ref_grads, ref_out) = got, ref
    assert loss.item() == pytest.approx(ref_loss.item(), rel=tol)
    for name in ref_parts:
        assert parts[name].item() == pytest.approx(ref_parts[name].item(), rel=tol, abs=tol * 1e-3), name
    for a, b in zip(grads, ref_grads):
        torch.testing.assert_close(a, b, rtol=0, atol=tol * 10 * float(b.abs().max()))
    for name in ("depth", "color", "weights"):
        torch.testing.assert_close(getattr(out, name), getattr(ref_out, name), rtol=0, atol=tol * 10)


def test_gradients_match_finite_differences():
    g = torch.Generator().manual_seed(0)
    R, N = 6, 7
    z = torch.sort(torch.rand(R, N, generator=g, dtype=torch.float64) * 2, -1).values
    depth = torch.rand(R, generator=g, dtype=torch.float64) + 0.5
    sdf = (torch.rand(R, N, generator=g, dtype=torch.float64) * 2 - 1).requires_grad_()
    rgb = torch.rand(R, N, 3, generator=g, dtype=torch.float64, requires_grad=True)
    beta = torch.tensor(4.0, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda s, b: fused_render.composite(s, b, z), (sdf, beta))
    weights = torch.rand(R, N, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(fused_render.color_sum, (weights, rgb))
    d_hat = torch.rand(R, generator=g, dtype=torch.float64, requires_grad=True)
    c_hat = torch.rand(R, 3, generator=g, dtype=torch.float64, requires_grad=True)
    color = torch.rand(R, 3, generator=g, dtype=torch.float64)
    with_depth = torch.tensor([True, True, False, True, True, True])
    rows = torch.tensor([True, False, True, True, True, True])

    def terms(s, dh, ch):
        return fused_render.loss_terms(s, z, dh, ch, depth, color, 0.3, with_depth, rows)

    assert torch.autograd.gradcheck(terms, (sdf, d_hat, c_hat))


def test_every_region_and_selection_counts_as_in_the_reference():
    # an empty region is 0, rays without depth feed the colour term only, rows drops rays from every term
    g = torch.Generator().manual_seed(2)
    R, N = 5, 4
    z = torch.tensor([[0.1, 0.2, 0.3, 0.4]] * R)
    depth = torch.tensor([0.25, 0.0, 0.5, 2.0, 0.3])  # ray 3: every sample in free space (no centre, no tail)
    sdf, d_hat, c_hat = torch.rand(R, N, generator=g), torch.rand(R, generator=g), torch.rand(R, 3, generator=g)
    color = torch.rand(R, 3, generator=g)
    for rows in (None, torch.tensor([True, True, False, True, True]), torch.tensor([False, True, False, True, False])):
        ref, ref_parts = total_loss(sdf, z, d_hat, c_hat, depth, color, 0.1, WEIGHTS, rows=rows)
        got, parts = total_loss(sdf, z, d_hat, c_hat, depth, color, 0.1, WEIGHTS, rows=rows, fused=True)
        assert got.item() == pytest.approx(ref.item(), rel=1e-6)
        assert [p.item() for p in parts.values()] == pytest.approx([p.item() for p in ref_parts.values()], rel=1e-6)
    assert parts["center"].item() == 0.0 and parts["tail"].item() == 0.0  # ray 3 alone has depth: free space only


def test_a_nan_sdf_makes_the_loss_nan_as_in_the_reference():
    z = torch.tensor([[0.1, 0.2, 0.3]])
    sdf = torch.tensor([[0.5, float("nan"), 0.1]], requires_grad=True)
    w, d = fused_render.composite(sdf, torch.tensor(10.0), z)
    c = fused_render.color_sum(w, torch.rand(1, 3, 3))
    assert torch.isnan(d).all() and torch.isnan(c).all()
    loss, _ = total_loss(sdf, z, d, c, torch.tensor([0.2]), torch.rand(1, 3), 0.1, WEIGHTS, fused=True)
    assert torch.isnan(loss)


def test_a_second_derivative_fails_loudly():
    z = torch.tensor([[0.1, 0.2, 0.3]])
    sdf = torch.tensor([[0.5, 0.2, 0.1]], requires_grad=True)
    _, d = fused_render.composite(sdf, torch.tensor(10.0), z)
    (g,) = torch.autograd.grad(d.sum(), sdf, create_graph=True)
    with pytest.raises(RuntimeError):
        g.sum().backward()


def test_a_call_no_kernel_can_take_is_refused_in_words():
    sdf, z = torch.rand(4, 3, dtype=torch.float16), torch.rand(4, 3, dtype=torch.float16)
    assert not fused_render.eligible(sdf, constant=(z,))
    with pytest.raises(RuntimeError, match="eligible"):
        fused_render.composite(sdf, torch.tensor(10.0, dtype=torch.float16), z)


def test_the_reference_runs_where_the_kernel_cannot():
    sdf = torch.rand(4, 3, requires_grad=True)
    z = torch.rand(4, 3)
    assert fused_render.eligible(sdf, constant=(z,))
    assert not fused_render.eligible(sdf, constant=(z.requires_grad_(),))  # a depth with a gradient
    assert not fused_render.eligible(sdf[:0], constant=(z[:0],))  # no rays
    assert not fused_render.eligible(sdf.double(), constant=(torch.rand(4, 3),))  # mixed dtypes
    D, dirs, _ = _rays(R=4)
    origins = torch.zeros(4, 3, requires_grad=True)
    for backend, fused_name in (("numba", "_CompositeBackward"), ("torch", "MulBackward0")):
        with kernels.use_backend(backend):
            assert fused_render.eligible(sdf, constant=(torch.rand(4, 3),)) == (backend == "numba")
            out = render_rays(origins, dirs, D + 1, lambda p: torch.tanh(1.5 - p[:, 2]), torch.sigmoid, 10.0, T, 3, 0,
                              None, False, None, 0.0, True)
            assert type(out.weights.grad_fn).__name__ == fused_name
