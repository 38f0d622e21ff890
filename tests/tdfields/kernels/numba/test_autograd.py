"""The numba kernels (tdfields.kernels.numba.autograd) against the pure-PyTorch reference, under fixed seeds."""

import pytest
import torch

import tdfields
from tdfields import kernels
from tdfields.interpolation import interpolate_reference
from tdfields.kernels.numba import autograd as numba_autograd
from tdfields.ops import compose_plane

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
    monkeypatch.setattr(numba_autograd, "_MAX_BUFFER_FLOATS", 10)
    grid = torch.randn(20, 20, 4, dtype=torch.float64, requires_grad=True)
    coords = torch.rand(500, 2, dtype=torch.float64) * 19
    (ga,) = torch.autograd.grad(interpolate_reference(grid, coords).sum(), grid)
    (gb,) = torch.autograd.grad(kernels.fused_interpolate(grid, coords).sum(), grid)
    torch.testing.assert_close(gb, ga)


def _small_field(kind: str, rank: int):
    """A 1 x 2 x 1 m field of ``kind`` at 0.1 m with 8 channels (``rank`` where the kind has one)."""
    spec = {"kind": kind, "aabb": [[0, 1], [0, 2], [0, 1]], "cell_size": 0.1, "channels": 8}
    if tdfields.KINDS[kind].has_rank:
        spec["rank"] = rank
    return tdfields.build(spec)


@pytest.mark.parametrize("kind", sorted(tdfields.KINDS))
def test_whole_fields_match_between_backends(kind):
    torch.manual_seed(0)
    f = _small_field(kind, rank=4)
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


@pytest.mark.parametrize("kind", sorted(tdfields.KINDS))
def test_points_with_zero_output_gradient_are_skipped_exactly(kind):
    # SLAM mapping gives a quarter of its points exactly zero feature gradients (rays without depth, dead ReLU
    # layers); the kernel skips them, which must change no factor gradient and leave their coordinate gradient 0
    torch.manual_seed(1)
    f = _small_field(kind, rank=3)
    x = (torch.rand(1500, 3) * torch.tensor([1.0, 2.0, 1.0])).requires_grad_(True)
    dead = torch.rand(1500) < 0.4
    dead[0] = dead[-1] = True
    out = {}
    for backend in ("torch", "numba"):
        with kernels.use_backend(backend):
            y = f(x)
            g = torch.randn(y.shape, generator=torch.Generator().manual_seed(2)) * (~dead)[:, None]
            out[backend] = torch.autograd.grad(y, [x, *f.parameters()], g)
    assert bool((out["numba"][0][dead] == 0).all())
    for a, b in zip(out["torch"], out["numba"]):
        torch.testing.assert_close(b, a, rtol=1e-4, atol=1e-5)


def test_second_derivative_raises_instead_of_silent_zero():
    f = tdfields.CP([[0, 1]] * 3, cell_size=0.25, channels=2, rank=2)
    x = torch.rand(10, 3, requires_grad=True)
    with kernels.use_backend("numba"):
        (g,) = torch.autograd.grad(f(x).sum(), x, create_graph=True)
        with pytest.raises(RuntimeError, match="differentiate twice"):
            g.sum().backward()


def _mixed_stack(dtype):
    """Coarse CP + fine Six-axis + a tri-plane level + VM + dense: every term shape in one program."""
    box = [[0, 1], [-0.5, 1.5], [0, 0.8]]
    levels = [
        tdfields.CP(box, grid_shape=(4, 5, 3), channels=3, rank=2),
        tdfields.SixAxis(box, grid_shape=(7, 6, 5), channels=3, rank=3, strategy="factors"),
        tdfields.SixAxis(box, grid_shape=(6, 5, 4), channels=3, rank=2, strategy="planes"),
        tdfields.TriPlane(box, grid_shape=(6, 7, 5), channels=2),
        tdfields.VectorMatrix(box, grid_shape=(5, 4, 6), channels=2, rank=2),
        tdfields.DenseGrid(box, grid_shape=(4, 4, 3), channels=2),
    ]
    return tdfields.MultiResolution(levels).to(dtype)


@pytest.mark.parametrize("wants", [(True, True), (True, False), (False, True)])
def test_multiresolution_program_matches_reference(wants):
    torch.manual_seed(1)
    f = _mixed_stack(torch.float64)
    for p in f.parameters():
        p.requires_grad_(wants[0])
    x = torch.rand(700, 3, dtype=torch.float64) * torch.tensor([1.4, 2.4, 1.2], dtype=torch.float64) - 0.2
    x[0] = torch.tensor([1.0, 1.5, 0.8])  # the far corner: every lower index clamped to size - 2
    x.requires_grad_(wants[1])
    inputs = [t for t, w in ((x, wants[1]),) if w] + ([p for p in f.parameters()] if wants[0] else [])
    out = {}
    for backend in ("torch", "numba"):
        with kernels.use_backend(backend):
            y = f(x)
            g = torch.randn_like(y, generator=torch.Generator().manual_seed(2))
            out[backend] = (y, torch.autograd.grad(y, inputs, g))
    assert out["numba"][0].shape == (700, f.out_dim)
    torch.testing.assert_close(out["numba"][0], out["torch"][0])
    for a, b in zip(out["torch"][1], out["numba"][1]):
        torch.testing.assert_close(b, a)


def test_generated_kernels_stay_in_bounds(monkeypatch, tmp_path):
    """Compile bounds-checked kernels (an out-of-range index raises IndexError) and run them at the box faces."""
    monkeypatch.setenv("TDFIELDS_KERNEL_BOUNDSCHECK", "1")
    monkeypatch.setenv("TDFIELDS_CACHE_DIR", str(tmp_path))
    box = [[0, 1], [-0.5, 1.5], [0, 0.8]]
    # factors spanning 1, 2 and 3 axes, terms of 1, 2 and 3 factors: every indexing pattern the generator writes
    f = tdfields.MultiResolution([tdfields.CP(box, grid_shape=(4, 5, 3), channels=3, rank=2),
                                  tdfields.VectorMatrix(box, grid_shape=(5, 4, 6), channels=2, rank=2),
                                  tdfields.DenseGrid(box, grid_shape=(4, 4, 3), channels=2)])
    x = torch.cat([torch.rand(50, 3) * 3 - 1, torch.tensor([[1.0, 1.5, 0.8], [0.0, -0.5, 0.0]])])
    x.requires_grad_(True)
    with kernels.use_backend("numba"):
        f(x).square().sum().backward()
    assert torch.isfinite(x.grad).all()
    assert any(tmp_path.rglob("tdfields_kernel_*.py"))


def test_second_derivative_through_a_larger_loss_raises():
    """The gradient used inside a loss that also has other terms must not silently act as a constant."""
    f = tdfields.SixAxis([[0, 1]] * 3, cell_size=0.25, channels=2, rank=2, strategy="factors")
    x = torch.rand(10, 3, requires_grad=True)
    with kernels.use_backend("numba"):
        y = f(x)
        (g,) = torch.autograd.grad(y.sum(), x, create_graph=True)
        loss = (g.norm(dim=-1) - 1).square().mean() + y.square().mean()
        with pytest.raises(RuntimeError, match="differentiate twice"):
            loss.backward()


def test_two_pass_backward_and_thread_split_match_one_pass(monkeypatch, three_threads):
    """Large factors take coordinate and factor gradients in two passes, large batches run on several threads:
    both must give the single-pass, single-thread result."""
    torch.manual_seed(3)
    f = tdfields.TriPlane([[0, 1]] * 3, grid_shape=(9, 8, 7), channels=4).double()
    x = torch.rand(9000, 3, dtype=torch.float64, requires_grad=True)

    def grads():
        with kernels.use_backend("numba"):
            y = f(x)
            return torch.autograd.grad(y.square().sum(), [x, *f.parameters()])

    base = grads()
    monkeypatch.setattr(numba_autograd, "_SPLIT_BACKWARD_FLOATS", 0)
    with three_threads():
        split = grads()
    for a, b in zip(base, split):
        torch.testing.assert_close(b, a)


@pytest.mark.parametrize("want", [(True, True), (True, False), (False, True)])
def test_fused_composition_matches_einsum(want):
    torch.manual_seed(0)
    u = torch.randn(11, 4 * 8, dtype=torch.float64, requires_grad=want[0])
    v = torch.randn(7, 4 * 8, dtype=torch.float64, requires_grad=want[1])
    ref = torch.einsum("akc,bkc->abc", u.view(11, 4, 8), v.view(7, 4, 8))
    with kernels.use_backend("numba"):
        fused = compose_plane(u, v, 4)
    torch.testing.assert_close(fused, ref)
    g = torch.randn_like(ref)
    inputs = [t for t, w in zip((u, v), want) if w]
    for a, b in zip(torch.autograd.grad(ref, inputs, g), torch.autograd.grad(fused, inputs, g)):
        torch.testing.assert_close(b, a)


def test_fused_composition_backward_with_mostly_zero_cells():
    """A query reads a fraction of a sub-plane's cells, so most of the plane's gradient is zero and the backward
    skips those cells; a cell with a gradient in any one channel (here only the last) must still count."""
    torch.manual_seed(1)
    u = torch.randn(13, 4 * 8, dtype=torch.float64, requires_grad=True)
    v = torch.randn(9, 4 * 8, dtype=torch.float64, requires_grad=True)
    g = torch.randn(13, 9, 8, dtype=torch.float64)
    cells = torch.rand(13, 9)
    g[cells > 0.3] = 0.0
    g[cells > 0.9, -1] = 1.5  # cells live in their last channel only
    ref = torch.einsum("akc,bkc->abc", u.view(13, 4, 8), v.view(9, 4, 8))
    with kernels.use_backend("numba"):
        fused = compose_plane(u, v, 4)
    for a, b in zip(torch.autograd.grad(ref, (u, v), g), torch.autograd.grad(fused, (u, v), g)):
        torch.testing.assert_close(b, a)


@pytest.mark.parametrize("want", [(True, True), (True, False), (False, True)])
def test_sub_plane_rows_match_composing_the_slices(want):
    """``rows`` composes a sub-plane from whole factors: the values of composing the two slices, bit for bit, and
    whole-factor gradients equal to the slices' scattered into zeros (what autograd's slicing gives), on two
    threads (the backward sums per-thread parts of v's gradient) as on one."""
    torch.manual_seed(2)
    u = torch.randn(150, 4 * 8, requires_grad=want[0])
    v = torch.randn(120, 4 * 8, requires_grad=want[1])
    rows = ((10, 140), (5, 115))  # 14300 cells: two threads split them (tdfields.kernels.threads.parts_for)
    read = torch.rand(400, 2) * torch.tensor([129.0, 109.0])
    inputs = [t for t, w in zip((u, v), want) if w]
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            with kernels.use_backend("numba"):
                sliced = compose_plane(u[10:140], v[5:115], 4, read_at=read)
                whole = compose_plane(u, v, 4, read_at=read, rows=rows)
            assert torch.equal(whole, sliced)
            g = torch.randn_like(sliced)
            for a, b in zip(torch.autograd.grad(sliced, inputs, g), torch.autograd.grad(whole, inputs, g)):
                assert torch.equal(b, a)
    finally:
        torch.set_num_threads(threads)
    ref = compose_plane(u, v, 4, rows=rows)  # the reference slices: same values to rounding
    torch.testing.assert_close(ref, torch.einsum("akc,bkc->abc", u[10:140].view(130, 4, 8),
                                                 v[5:115].view(110, 4, 8)))
    with pytest.raises(ValueError, match="rows"):
        kernels.fused_compose_plane(u, v, 4, rows=((10, 151), (5, 115)))


def test_empty_batches():
    f = tdfields.MultiResolution([tdfields.CP([[0, 1]] * 3, cell_size=0.25, channels=2, rank=2),
                                  tdfields.SixAxis([[0, 1]] * 3, cell_size=0.25, channels=2, rank=2)])
    x = torch.zeros(0, 3, requires_grad=True)
    with kernels.use_backend("numba"):
        y = f(x)
        y.sum().backward()
    assert y.shape == (0, 4) and x.grad.shape == (0, 3)


def test_composition_above_the_fused_rank_limit_takes_the_reference(monkeypatch):
    """Above FUSED_COMPOSE_MAX_RANK the generated compose kernel is 5-16x slower than einsum
    (benchmarks/compose_rank.py at f5975fa, since retired): dispatch goes to the reference there, and at the limit still to the kernel."""
    from tdfields import ops

    calls = []
    real = ops.kernels.fused_compose_plane
    monkeypatch.setattr(ops.kernels, "fused_compose_plane",
                        lambda u, v, k, read_at=None, rows=None: calls.append(k) or real(u, v, k, read_at, rows))
    for rank in (ops.FUSED_COMPOSE_MAX_RANK, ops.FUSED_COMPOSE_MAX_RANK + 1):
        u, v = torch.randn(5, rank * 2), torch.randn(6, rank * 2)
        with kernels.use_backend("numba"):
            out = ops.compose_plane(u, v, rank)
        torch.testing.assert_close(out, torch.einsum("akc,bkc->abc", u.view(5, rank, 2), v.view(6, rank, 2)))
    assert calls == [ops.FUSED_COMPOSE_MAX_RANK]
