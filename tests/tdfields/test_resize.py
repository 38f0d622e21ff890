import pytest
import torch

import tdfields

from .conftest import make


def test_upsample_preserves_function_exactly_for_linear_factors(kind):
    """Refining by an integer factor keeps every old sample, and linear factors keep their interpolant."""
    f = make(kind, shape=(3, 3, 3)).double()
    x = torch.rand(50, 3, dtype=torch.float64) * 1.2 - 0.5
    before = f(x).detach()
    tdfields.resize(f, grid_shape=(5, 5, 5))  # (n-1) doubles: new samples are midpoints
    assert f.grid_shape == (5, 5, 5)
    assert f.num_parameters() == f.closed_form_parameters()
    if kind in ("triplane", "dense_grid", "cp", "six_axis", "vector_matrix"):
        # each factor is piecewise linear in its own axes, and refining by 2 keeps it exactly
        torch.testing.assert_close(f(x), before)


def test_resize_keeps_adam_state_and_trains_on(kind):
    f = make(kind)
    opt = torch.optim.Adam(f.parameters(), lr=1e-2)
    x = torch.rand(64, 3)
    for _ in range(3):
        opt.zero_grad()
        f(x).square().mean().backward()
        opt.step()
    old = {n: p for n, p in f.factors.items()}
    steps = {n: opt.state[p]["step"] for n, p in old.items()}
    tdfields.resize(f, grid_shape=(9, 7, 11), optimizer=opt)
    for name, p in f.factors.items():
        assert p is not old[name]
        assert any(p is q for g in opt.param_groups for q in g["params"])
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape
        assert torch.equal(torch.as_tensor(st["step"]), torch.as_tensor(steps[name]))
        assert (st["exp_avg_sq"] >= 0).all()
    opt.zero_grad()
    f(x).square().mean().backward()
    opt.step()  # would raise if state and parameters disagreed


def test_resize_box_samples_old_field():
    f = tdfields.TriPlane([[0, 1], [0, 1], [0, 1]], grid_shape=(11, 11, 11), channels=2).double()
    x = torch.rand(40, 3, dtype=torch.float64) * 0.5
    before = f(x).detach()
    tdfields.resize(f, aabb=[[0, 0.5], [0, 0.5], [0, 0.5]], grid_shape=(6, 6, 6))  # same spacing, sub-box
    torch.testing.assert_close(f.aabb, torch.tensor([[0, 0.5]] * 3, dtype=torch.float64))
    torch.testing.assert_close(f(x), before)


def test_resize_by_cell_size():
    f = tdfields.CP([[0, 1], [0, 2], [0, 1]], cell_size=0.5, channels=2, rank=2)
    tdfields.resize(f, cell_size=0.1)
    assert f.grid_shape == (10, 20, 10)


def test_resize_rejects_both():
    f = make("cp")
    with pytest.raises(ValueError, match="not both"):
        tdfields.resize(f, grid_shape=(4, 4, 4), cell_size=0.1)


def test_grow_copies_the_old_samples_and_keeps_the_function(kind):
    """Growing by whole samples copies every old sample (and Adam's moments) bit for bit, and the field is the
    same function wherever it was queried, outside the old box too (queries there were clamped to the border,
    which the new samples copy)."""
    f = make(kind).double()
    x = torch.rand(200, 3, dtype=torch.float64) * 3 - 1  # inside the old box and around it
    opt = torch.optim.Adam(f.parameters(), lr=1e-2)
    f(x).square().mean().backward()
    opt.step()
    old = {n: p.detach().clone() for n, p in f.factors.items()}
    moments = {n: opt.state[p]["exp_avg"].clone() for n, p in f.factors.items()}
    old_box, old_shape = f.aabb.clone(), f.grid_shape
    before = f(x).detach()
    lower, upper = (2, 0, 1), (0, 3, 1)
    tdfields.grow(f, lower, upper, optimizer=opt)
    assert f.grid_shape == tuple(n + lo + hi for n, lo, hi in zip(old_shape, lower, upper))
    assert f.num_parameters() == f.closed_form_parameters()
    step = (old_box[:, 1] - old_box[:, 0]) / (torch.tensor(old_shape, dtype=torch.float64) - 1)
    torch.testing.assert_close(f.aabb[:, 0], old_box[:, 0] - step * torch.tensor(lower, dtype=torch.float64))
    torch.testing.assert_close(f.aabb[:, 1], old_box[:, 1] + step * torch.tensor(upper, dtype=torch.float64))
    for name, spec in f.factor_specs().items():
        inner = (*(slice(lower[a], lower[a] + old_shape[a]) for a in spec.axes), slice(None))
        assert torch.equal(f.factors[name].detach()[inner], old[name])
        assert torch.equal(opt.state[f.factors[name]]["exp_avg"][inner], moments[name])
    torch.testing.assert_close(f(x), before)
    opt.zero_grad()
    f(x).square().mean().backward()
    opt.step()  # would raise if state and parameters disagreed


def test_grow_rejects_negative_counts():
    f = make("cp")
    with pytest.raises(ValueError, match="sample counts"):
        tdfields.grow(f, (0, -1, 0), (0, 0, 0))
