"""Six-axis plane composition: cached while the factors are frozen and unchanged, recomputed after any change."""

import torch

import tdfields


def _field():
    torch.manual_seed(0)
    return tdfields.SixAxis([[0, 1], [0, 2], [0, 1]], cell_size=0.1, channels=4, rank=3)


def test_frozen_queries_reuse_planes_until_a_step_changes_the_factors():
    f = _field()
    x = torch.rand(50, 3) * torch.tensor([1.0, 2.0, 1.0])
    opt = torch.optim.Adam(f.parameters(), lr=0.1)
    f.requires_grad_(False)
    first = f.composed_planes()
    assert f.composed_planes() is first  # frozen and unchanged: the same tensors
    with torch.no_grad():
        before = f(x)
    f.requires_grad_(True)
    assert f.use_planes(1) is False or f.strategy != "auto"  # a tiny batch with gradients takes the factor path
    f(x).square().sum().backward()
    opt.step()  # in-place update: every factor's version counter advances
    f.requires_grad_(False)
    second = f.composed_planes()
    assert second is not first
    with torch.no_grad():
        after = f(x)
    assert not torch.allclose(before, after)
    # the cached planes equal a fresh composition
    for plane, cached in zip(("xy", "yz", "zx"), second):
        torch.testing.assert_close(cached, f.composed_plane(plane))


def test_cache_follows_load_state_dict_and_dtype_moves():
    f, g = _field(), _field()
    with torch.no_grad():
        for p in g.parameters():
            p.add_(1.0)
    f.requires_grad_(False)
    a = f.composed_planes()
    f.load_state_dict(g.state_dict())
    b = f.composed_planes()
    assert b is not a
    torch.testing.assert_close(b[0], g.composed_plane("xy"))
    f.double()
    assert f.composed_planes()[0].dtype == torch.float64


def test_clear_cache_after_data_edits():
    f = _field()
    f.requires_grad_(False)
    a = f.composed_planes()
    f.factors["xy_x"].data.mul_(2)  # .data bypasses the version counter
    f.clear_cache()
    assert f.composed_planes() is not a


def test_cached_queries_keep_point_gradients():
    f = _field()
    f.requires_grad_(False)
    x = (torch.rand(30, 3) * torch.tensor([1.0, 2.0, 1.0])).requires_grad_(True)
    (g_cached,) = torch.autograd.grad(f(x).sum(), x)
    f.strategy = "factors"
    (g_factors,) = torch.autograd.grad(f(x).sum(), x)
    torch.testing.assert_close(g_cached, g_factors, rtol=1e-4, atol=1e-5)
