"""The render tail's Triton kernels (``slam.core.render_kernels_triton``) against the PyTorch reference and the numba
kernels: compiled on a CUDA device when TRITON_INTERPRET=0 and one is present, else in Triton's interpreter on CPU
tensors (tests/conftest.py sets TRITON_INTERPRET=1 without a GPU)."""

import os

import pytest
import torch

from slam.core import fused_render
from slam.core.losses import total_loss
from tdfields import kernels
from tests.slam.core.test_fused_render import WEIGHTS, _loss_and_grads, assert_matches_reference

pytest.importorskip("triton")
INTERPRET = os.environ.get("TRITON_INTERPRET", "") not in ("", "0")
DEVICE = "cpu" if INTERPRET else "cuda"
pytestmark = pytest.mark.skipif(not INTERPRET and not torch.cuda.is_available(),
                                reason="Triton needs a CUDA device, or TRITON_INTERPRET=1 before triton is imported")


@pytest.fixture
def launches(monkeypatch):
    """Counts of the tail's kernel launches by backend, so a test can tell the Triton kernels really ran."""
    counts = {"numba": 0, "triton": 0}
    real = fused_render._launch

    def counted(backend, name, *args):
        counts[backend] += 1
        real(backend, name, *args)

    monkeypatch.setattr(fused_render, "_launch", counted)
    return counts


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-6), (torch.float64, 1e-12)])
@pytest.mark.parametrize("cutoff", [0.0, 1e-3])
def test_render_and_loss_match_the_reference_to_rounding(dtype, tol, cutoff, launches):
    # 300 rays: two whole blocks of 128 and a partial one
    rows = (torch.rand(300, generator=torch.Generator().manual_seed(1)) > 0.2).to(DEVICE)  # the tracker's inliers
    with kernels.use_backend("torch"):
        ref = _loss_and_grads(True, cutoff, dtype, rows, DEVICE, R=300)
    with kernels.use_backend("triton"):
        got = _loss_and_grads(True, cutoff, dtype, rows, DEVICE, R=300)
    assert launches == {"numba": 0, "triton": 6}  # three Functions, forward and backward
    assert_matches_reference(got, ref, tol)


def test_gradients_match_finite_differences(launches):
    g = torch.Generator().manual_seed(0)
    R, N = 4, 5

    def rand(*shape, grad=False):
        return (torch.rand(*shape, generator=g, dtype=torch.float64)).to(DEVICE).requires_grad_(grad)

    z = torch.sort(rand(R, N) * 2, -1).values
    depth, sdf, rgb = rand(R) + 0.5, (rand(R, N) * 2 - 1).detach().requires_grad_(), rand(R, N, 3, grad=True)
    beta = torch.tensor(4.0, dtype=torch.float64, device=DEVICE, requires_grad=True)
    weights, d_hat, c_hat, color = rand(R, N, grad=True), rand(R, grad=True), rand(R, 3, grad=True), rand(R, 3)
    with_depth = torch.tensor([True, False, True, True], device=DEVICE)
    rows = torch.tensor([True, True, False, True], device=DEVICE)
    with kernels.use_backend("triton"):
        assert torch.autograd.gradcheck(lambda s, b: fused_render.composite(s, b, z), (sdf, beta))
        assert torch.autograd.gradcheck(fused_render.color_sum, (weights, rgb))
        assert torch.autograd.gradcheck(
            lambda s, dh, ch: fused_render.loss_terms(s, z, dh, ch, depth, color, 0.3, with_depth, rows),
            (sdf, d_hat, c_hat))
    assert launches["numba"] == 0 and launches["triton"] > 0


def test_every_region_and_selection_counts_as_in_the_reference():
    g = torch.Generator().manual_seed(2)
    R, N = 5, 4
    z = torch.tensor([[0.1, 0.2, 0.3, 0.4]] * R, device=DEVICE)
    depth = torch.tensor([0.25, 0.0, 0.5, 2.0, 0.3], device=DEVICE)  # ray 3: every sample in free space
    sdf, d_hat, c_hat, color = (torch.rand(*s, generator=g).to(DEVICE) for s in ((R, N), (R,), (R, 3), (R, 3)))
    for rows in (None, torch.tensor([True, True, False, True, True]), torch.tensor([False, True, False, True, False])):
        rows = None if rows is None else rows.to(DEVICE)
        ref, ref_parts = total_loss(sdf, z, d_hat, c_hat, depth, color, 0.1, WEIGHTS, rows=rows)
        with kernels.use_backend("triton"):
            got, parts = total_loss(sdf, z, d_hat, c_hat, depth, color, 0.1, WEIGHTS, rows=rows, fused=True)
        assert got.item() == pytest.approx(ref.item(), rel=1e-6)
        assert [p.item() for p in parts.values()] == pytest.approx([p.item() for p in ref_parts.values()], rel=1e-6)
    assert parts["center"].item() == 0.0 and parts["tail"].item() == 0.0


def test_a_nan_sdf_makes_the_loss_nan_as_in_the_reference():
    z = torch.tensor([[0.1, 0.2, 0.3]], device=DEVICE)
    sdf = torch.tensor([[0.5, float("nan"), 0.1]], device=DEVICE, requires_grad=True)
    with kernels.use_backend("triton"):
        w, d = fused_render.composite(sdf, torch.tensor(10.0, device=DEVICE), z)
        c = fused_render.color_sum(w, torch.rand(1, 3, 3).to(DEVICE))
        loss, _ = total_loss(sdf, z, d, c, torch.tensor([0.2], device=DEVICE), torch.rand(1, 3).to(DEVICE), 0.1,
                             WEIGHTS, fused=True)
    assert torch.isnan(d).all() and torch.isnan(c).all() and torch.isnan(loss)


@pytest.mark.skipif(not INTERPRET, reason="the numba kernels run on CPU tensors")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_kernels_agree_with_numba(dtype, launches):
    # the same arithmetic in the same order per ray: values and every gradient equal to the numba kernels' to an ulp
    def run(backend):
        with kernels.use_backend(backend):
            loss, parts, grads, out = _loss_and_grads(True, 1e-3, dtype, R=200)
        return [t.detach() for t in (loss, *parts.values(), *grads, out.depth, out.color, out.weights)]

    eps = torch.finfo(dtype).eps
    for a, b in zip(run("triton"), run("numba")):
        torch.testing.assert_close(a, b, rtol=4 * eps, atol=4 * eps * float(b.abs().max()))
    assert launches["numba"] == launches["triton"] == 6
