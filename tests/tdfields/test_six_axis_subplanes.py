"""Six-axis mapping queries compose only the part of each plane the points touch."""

import pytest
import torch

import tdfields
import tdfields.six_axis as six_axis_module
from tdfields import kernels

BOX = [[0.0, 2.0], [0.0, 1.0], [0.0, 1.5]]


def _field(strategy):
    torch.manual_seed(0)
    return tdfields.SixAxis(BOX, grid_shape=(21, 11, 16), channels=4, rank=3, strategy=strategy).double()


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("region", ["corner", "edge", "one point", "everywhere"])
def test_subplanes_match_the_factor_path(monkeypatch, backend, region):
    torch.manual_seed(1)
    if region == "corner":
        x = torch.rand(500, 3, dtype=torch.float64) * torch.tensor([0.5, 0.3, 0.4]) + torch.tensor([0.2, 0.1, 0.3])
    elif region == "edge":  # on the upper faces and beyond: clamped
        x = torch.rand(300, 3, dtype=torch.float64) * 0.4 + torch.tensor([1.8, 0.8, 1.3])
    elif region == "one point":
        x = torch.tensor([[0.77, 0.31, 0.52]], dtype=torch.float64)
    else:
        x = torch.rand(800, 3, dtype=torch.float64) * torch.tensor([2.0, 1.0, 1.5])
    shapes = []
    compose = six_axis_module.compose_plane
    def sub_plane(u, v, rows):
        return (u.shape[0], v.shape[0]) if rows is None else (rows[0][1] - rows[0][0], rows[1][1] - rows[1][0])

    monkeypatch.setattr(six_axis_module, "compose_plane", lambda u, v, k, read_at=None, rows=None: shapes.append(
        sub_plane(u, v, rows)) or compose(u, v, k, read_at=read_at, rows=rows))
    results = []
    for strategy in ("planes", "factors"):
        f = _field(strategy)
        xi = x.clone().requires_grad_()
        with kernels.use_backend(backend):
            y = f(xi)
            grads = torch.autograd.grad(y.square().sum(), [xi, *f.parameters()])
        results.append((y, grads))
    torch.testing.assert_close(results[0][0], results[1][0])
    for a, b in zip(results[0][1], results[1][1]):
        torch.testing.assert_close(a, b)
    full = {(21, 11), (11, 16), (16, 21)}
    if region == "everywhere":
        assert set(shapes) == full
    else:
        assert len(shapes) == 3 and all(a * b < 0.3 * 21 * 16 for a, b in shapes)  # a small part of each plane


def test_the_kernel_composes_only_the_cells_the_points_read(monkeypatch):
    """On the numba path a sub-plane is composed only where the plan's points interpolate (the rest 0), and the
    query is the same bit for bit as with every cell of the region composed; points on cell borders and on the
    region's upper edge included."""
    torch.manual_seed(2)
    x = torch.rand(40, 3, dtype=torch.float64) * torch.tensor([1.2, 0.6, 0.9]) + 0.1
    x[:10] = torch.round(x[:10] * 10) / 10  # on grid lines: the lower index is the point's own
    x[10] = torch.tensor([1.3, 0.7, 1.0])  # the box's upper corner, on grid lines: its lower index is clamped
    f = _field("planes")
    with kernels.use_backend("numba"):
        planes = tdfields.plan(f, x).tensors
        sparse = [float((p == 0).all(-1).double().mean()) for p in planes]
        y = f(x.clone().requires_grad_())
        grads = torch.autograd.grad(y.square().sum(), list(f.parameters()))
        compose = six_axis_module.compose_plane
        monkeypatch.setattr(six_axis_module, "compose_plane",
                            lambda u, v, k, read_at=None, rows=None: compose(u, v, k, rows=rows))
        assert all(not (p == 0).all(-1).any() for p in tdfields.plan(f, x).tensors)
        y_full = f(x.clone().requires_grad_())
        grads_full = torch.autograd.grad(y_full.square().sum(), list(f.parameters()))
    assert min(sparse) > 0.05  # 40 points leave cells of their bounding box unread, and those stay 0
    assert torch.equal(y, y_full)
    for a, b in zip(grads, grads_full):
        assert torch.equal(a, b)


def test_frozen_queries_still_use_the_cached_full_planes():
    f = _field("auto")
    x = torch.rand(50, 3, dtype=torch.float64) * 0.2
    with tdfields.frozen(f):
        tensors = tdfields.plan(f, x).tensors
        assert [t.shape[:2] for t in tensors] == [(21, 11), (11, 16), (16, 21)]
        assert tensors[0] is f.composed_planes()[0]


def test_nan_and_empty_batches_keep_working():
    f = _field("planes")
    with kernels.use_backend("numba"):
        y = f(torch.zeros(0, 3, dtype=torch.float64, requires_grad=True))
        assert y.shape == (0, 4)
        x = torch.tensor([[float("nan"), 0.5, 0.5], [0.5, 0.5, 0.5]], dtype=torch.float64)
        out = f(x)
    assert torch.isfinite(out[1]).all()
