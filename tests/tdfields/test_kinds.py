"""Every kind: closed-form parameter counts, interpolation against a dense reference, gradients."""

import math

import pytest
import torch
import torch.nn.functional as F
from einops import rearrange

import tdfields
from tdfields import kernels

from .conftest import BOX, SHAPE, make


def formula(kind, n, C, k):
    """The parameter counts of docs/tdfields.md, written out independently of the library."""
    nx, ny, nz = n
    k = k or 0
    return {
        "dense_grid": C * nx * ny * nz,
        "triplane": C * (nx * ny + nx * nz + ny * nz),
        "vector_matrix": k * C * (ny * nz + nx + nx * nz + ny + nx * ny + nz),
        "cp": k * C * (nx + ny + nz),
        "six_axis": 2 * k * C * (nx + ny + nz),
    }[kind]


@pytest.mark.parametrize("shape", [(5, 4, 6), (17, 3, 9)])
@pytest.mark.parametrize("channels", [1, 8])
def test_parameter_count_equals_closed_form(kind, shape, channels):
    f = make(kind, channels=channels, shape=shape)
    expected = formula(kind, shape, channels, f.rank)
    assert f.num_parameters() == expected
    assert sum(p.numel() for p in f.parameters()) == expected
    assert f.closed_form_parameters() == expected
    assert sum(f.parameter_breakdown().values()) == expected
    assert f.memory_bytes() == 4 * expected
    assert "aabb" not in dict(f.named_parameters())
    assert tuple(f.aabb.shape) == (3, 2)


def test_complexity_labels():
    expected = {"dense_grid": "O(n^3)", "triplane": "O(n^2)", "vector_matrix": "O(n^2)", "cp": "O(n)",
                "six_axis": "O(n)"}
    assert {k: cls.complexity for k, cls in tdfields.KINDS.items()} == expected


def dense_volume(f):
    """[C, n_z, n_y, n_x] volume of the field's values at its grid samples, from the factors by einsum."""
    fa = {k: v.detach() for k, v in f.factors.items()}
    k = f.rank
    if f.kind == "dense_grid":
        vol = fa["volume"]
    elif f.kind == "triplane":
        vol = fa["xy"][:, :, None] + fa["xz"][:, None, :] + fa["yz"][None, :, :]
    else:
        sp = {n: rearrange(t, "... (k c) -> ... k c", k=k) for n, t in fa.items()}
        if f.kind == "cp":
            vol = torch.einsum("xkc,ykc,zkc->xyzc", sp["x"], sp["y"], sp["z"])
        elif f.kind == "six_axis":
            vol = (torch.einsum("xkc,ykc->xyc", sp["xy_x"], sp["xy_y"])[:, :, None]
                   + torch.einsum("ykc,zkc->yzc", sp["yz_y"], sp["yz_z"])[None]
                   + torch.einsum("zkc,xkc->xzc", sp["zx_z"], sp["zx_x"])[:, None])
        else:  # vector_matrix
            vol = (torch.einsum("yzkc,xkc->xyzc", sp["plane_yz_x"], sp["line_yz_x"])
                   + torch.einsum("xzkc,ykc->xyzc", sp["plane_xz_y"], sp["line_xz_y"])
                   + torch.einsum("xykc,zkc->xyzc", sp["plane_xy_z"], sp["line_xy_z"]))
    return vol.permute(3, 2, 1, 0).contiguous()


@pytest.mark.parametrize("backend", ["torch", "auto"])
def test_matches_dense_trilinear_reference(kind, backend):
    """Products of linear interpolants equal trilinear interpolation of the dense product volume."""
    f = make(kind).double()
    box = f.aabb  # the float32-rounded box the field stores, as float64
    g = torch.Generator().manual_seed(1)
    pts = box[:, 0] + torch.rand(500, 3, generator=g, dtype=torch.float64) * (box[:, 1] - box[:, 0])
    with kernels.use_backend(backend):
        ours = f(pts)
    grid = (2 * (pts - box[:, 0]) / (box[:, 1] - box[:, 0]) - 1).view(1, 1, 1, -1, 3)
    ref = F.grid_sample(dense_volume(f)[None], grid, mode="bilinear", align_corners=True).view(f.channels, -1).T
    torch.testing.assert_close(ours, ref, rtol=1e-10, atol=1e-12)


def test_values_at_grid_samples_equal_factors(kind):
    f = make(kind).double()
    box = f.aabb
    idx = torch.tensor([[0, 0, 0], [4, 3, 5], [2, 1, 3]])
    pts = box[:, 0] + idx.double() / (torch.tensor(SHAPE) - 1) * (box[:, 1] - box[:, 0])
    vol = dense_volume(f)  # [C, z, y, x]
    expected = torch.stack([vol[:, z, y, x] for x, y, z in idx.tolist()])
    torch.testing.assert_close(f(pts), expected)


def test_leading_dims_kept(kind):
    f = make(kind)
    pts = torch.rand(2, 3, 7, 3)
    assert f(pts).shape == (2, 3, 7, f.out_dim)
    assert f(torch.rand(3)).shape == (f.out_dim,)


@pytest.mark.parametrize("backend", ["torch", "auto"])
def test_gradcheck_points_and_parameters(kind, backend):
    f = make(kind, channels=2, shape=(4, 3, 5)).double()
    g = torch.Generator().manual_seed(2)
    box = f.aabb
    # keep points away from cell boundaries, where the interpolant has kinks
    pts = (box[:, 0] + (0.1 + 0.8 * torch.rand(6, 3, generator=g, dtype=torch.float64)) * (box[:, 1] - box[:, 0]))
    pts.requires_grad_(True)
    params = list(f.parameters())

    def fn(p, *factors):
        return torch.func.functional_call(f, {f"factors.{n}": t for n, t in zip(f.factors.keys(), factors)}, (p,))

    with kernels.use_backend(backend):
        assert torch.autograd.gradcheck(fn, (pts, *[p.detach().clone().requires_grad_(True) for p in params]))


def test_second_derivatives_exist(kind):
    """Eikonal-style losses need d/dtheta of d f / d x."""
    f = make(kind, channels=1).double()
    pts = (f.aabb[:, 0] + 0.37 * (f.aabb[:, 1] - f.aabb[:, 0])).repeat(3, 1) + torch.rand(3, 3, dtype=torch.float64) * 0.05
    pts.requires_grad_(True)
    with kernels.use_backend("torch"):  # the fused kernels are first-order only
        (grad,) = torch.autograd.grad(f(pts).sum(), pts, create_graph=True)
        grad.norm(dim=-1).sum().backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in f.parameters())


def test_points_outside_clamp_to_border(kind):
    f = make(kind)
    inside = torch.tensor([[0.7, 1.0, 0.4], [-0.5, 0.5, 0.0]])
    outside = torch.tensor([[5.0, 3.0, 2.0], [-9.0, 0.5, 0.0]])
    torch.testing.assert_close(f(outside), f(inside))
    assert f.contains(inside).all() and not f.contains(outside).any()
    p = outside.clone().requires_grad_(True)
    f(p).sum().backward()
    assert torch.all(p.grad[0] == 0)


def test_six_axis_strategies_agree():
    f = make("six_axis", channels=5).double()
    pts = torch.rand(300, 3, dtype=torch.float64) * 1.4 - 0.4
    f.strategy = "factors"
    a = f(pts)
    f.strategy = "planes"
    b = f(pts)
    torch.testing.assert_close(a, b)
    pa = pts.clone().requires_grad_(True)
    f.strategy = "factors"
    ga = torch.autograd.grad(f(pa).square().sum(), [pa, *f.parameters()])
    f.strategy = "planes"
    gb = torch.autograd.grad(f(pa).square().sum(), [pa, *f.parameters()])
    for x, y in zip(ga, gb):
        torch.testing.assert_close(x, y)


def test_six_axis_auto_strategy_depends_on_batch():
    f = make("six_axis", channels=4, shape=(50, 50, 50))  # planes: 4*7500 = 30000 floats
    assert not f.use_planes(100)        # 100 * 3 * 4 = 1200 < 30000 -> factors
    assert f.use_planes(10_000)         # 120000 > 30000 -> planes


@pytest.mark.parametrize("bad, match", [
    ({"grid_shape": [1, 4, 4]}, "grid_shape"),
    ({"channels": 0}, "channels"),
])
def test_bad_construction_names_problem(kind, bad, match):
    kw = {"grid_shape": [4, 4, 4], "channels": 2, **bad}
    cls = tdfields.KINDS[kind]
    extra = {"rank": 2} if cls.has_rank else {}
    with pytest.raises(ValueError, match=match):
        cls(BOX, **kw, **extra)


def test_rank_validation():
    with pytest.raises(ValueError, match="rank"):
        tdfields.CP(BOX, grid_shape=[4, 4, 4], channels=2)
    with pytest.raises(ValueError, match="no rank"):
        tdfields.TriPlane(BOX, grid_shape=[4, 4, 4], channels=2, rank=3)
    with pytest.raises(ValueError, match="exactly one"):
        tdfields.TriPlane(BOX, channels=2)


def test_bad_points_shape():
    f = make("cp")
    with pytest.raises(ValueError, match=r"\[\.\.\., 3\]"):
        f(torch.rand(10, 2))


def test_points_are_not_detached(kind):
    f = make(kind)
    p = torch.tensor([[0.1, 0.5, 0.05]], requires_grad=True)
    f(p).sum().backward()
    assert p.grad is not None and math.isfinite(p.grad.abs().sum().item())
