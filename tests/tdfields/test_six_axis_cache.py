"""Six-axis plane cache: alive only inside ``tdfields.frozen``, so a query never reads an old map.

Every test compares against a field that has never cached anything (built fresh from the same state_dict), after
the writes SLAM and users really make: fused / foreach / plain Adam, SGD, load_state_dict, resize, dtype moves.
"""

import pytest
import torch

import tdfields

BOX = [[0, 1], [0, 2], [0, 1]]


def _field(seed=0):
    torch.manual_seed(seed)
    return tdfields.SixAxis(BOX, cell_size=0.1, channels=4, rank=3)


def _points(n=200, seed=1):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, generator=g) * torch.tensor([1.0, 2.0, 1.0])


def _fresh_copy(f):
    g = tdfields.SixAxis(f.aabb.tolist(), grid_shape=f.grid_shape, channels=f.channels, rank=f.rank).to(
        f.factors["xy_x"].dtype)
    g.load_state_dict(f.state_dict())
    return g


OPTIMIZERS = {
    "adam-fused": lambda p: torch.optim.Adam(p, lr=0.05, fused=True),
    "adam-foreach": lambda p: torch.optim.Adam(p, lr=0.05, foreach=True),
    "adam-plain": lambda p: torch.optim.Adam(p, lr=0.05, foreach=False),
    "adamw-fused": lambda p: torch.optim.AdamW(p, lr=0.05, fused=True),
    "sgd": lambda p: torch.optim.SGD(p, lr=0.5, momentum=0.9),
}


@pytest.mark.parametrize("name", sorted(OPTIMIZERS))
def test_queries_after_any_optimizer_step_read_the_new_factors(name):
    f = _field()
    x = _points()
    opt = OPTIMIZERS[name](f.parameters())
    for _ in range(3):  # SLAM's order: frozen query (tracking), then a mapping step, repeated
        with tdfields.frozen(f), torch.no_grad():
            f(x)
        f(_points(4000, seed=2)).square().sum().backward()
        opt.step()
        opt.zero_grad()
        ref = _fresh_copy(f)
        with torch.no_grad():
            torch.testing.assert_close(f(x), ref(x))  # outside frozen
        with tdfields.frozen(f):
            torch.testing.assert_close(f(x), ref(x))  # inside frozen, with the point graph on
            with torch.no_grad():
                torch.testing.assert_close(f(x), ref(x))


def test_frozen_block_caches_once_and_drops_on_exit():
    f = _field()
    with tdfields.frozen(f):
        assert all(not p.requires_grad for p in f.parameters())
        first = f.composed_planes()
        assert f.composed_planes() is first
        assert f.use_planes(1)  # a frozen field always reads its cached planes
    assert f._plane_cache is None
    assert all(p.requires_grad for p in f.parameters())
    assert f.composed_planes() is not f.composed_planes()  # outside a block nothing is kept


def test_nested_blocks_and_a_module_holding_fields():
    scene = torch.nn.ModuleDict({"a": _field(0), "b": tdfields.build(
        {"kind": "six_axis", "aabb": BOX, "cell_size": [0.5, 0.1], "channels": 4, "rank": 2})})
    fields = [m for m in scene.modules() if isinstance(m, tdfields.Field)]
    assert len(fields) == 3
    with tdfields.frozen(scene):
        with tdfields.frozen(scene["a"]):
            assert all(f.is_frozen for f in fields)
        assert scene["a"].is_frozen  # the outer block still holds it
    assert not any(f.is_frozen for f in fields)


def test_load_state_dict_and_resize_inside_a_block_are_seen():
    f, g = _field(0), _field(5)
    x = _points()
    with tdfields.frozen(f):
        f.composed_planes()
        f.load_state_dict(g.state_dict())  # copy_ under no_grad advances the version counter
        torch.testing.assert_close(f(x), g(x))
    h = tdfields.resize(f, grid_shape=(8, 15, 9))
    with tdfields.frozen(h):
        torch.testing.assert_close(h(x), _fresh_copy(h)(x))


def test_dtype_moves_drop_the_cache():
    f = _field()
    with tdfields.frozen(f):
        f.composed_planes()
        f.double()
        assert f.composed_planes()[0].dtype == torch.float64


def test_cached_queries_keep_point_gradients():
    f = _field()
    x = _points(30).requires_grad_(True)
    with tdfields.frozen(f):
        (g_cached,) = torch.autograd.grad(f(x).sum(), x)
    f.strategy = "factors"
    (g_factors,) = torch.autograd.grad(f(x).sum(), x)
    torch.testing.assert_close(g_cached, g_factors, rtol=1e-4, atol=1e-5)


def test_no_grad_queries_outside_a_block_choose_the_cheaper_exact_path():
    f = _field()
    x = _points(20)
    with torch.no_grad():
        tensors = f.plan_at(tdfields.to_grid_coords(x, f.aabb, f.grid_shape)[None]).tensors
    assert len(tensors) == 6  # 20 points: the factor path (composing planes would cost more)
