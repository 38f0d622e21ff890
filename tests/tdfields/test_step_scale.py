"""Step scales: closed forms, and one real Adam step moving every kind's features about as far as a plane's."""

import math

import pytest
import torch

import tdfields
from tdfields.step_scale import scaled_param_groups, step_scales

from .conftest import make

M = 0.3    # every factor entry is +-M below: the closed forms then hold exactly
LR = 1e-3


def _constant_magnitude(field, seed=0):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in field.parameters():
            p.copy_(M * (torch.randint(0, 2, p.shape, generator=g) * 2 - 1).to(p.dtype))
    return field


def test_single_factor_kinds_keep_their_rate_exactly():
    for kind in ("triplane", "dense_grid"):
        f = make(kind)
        assert set(step_scales(f).values()) == {1.0}
        for mode in ("matched", "lift", "none"):
            groups = scaled_param_groups(f, 0.005, mode)
            assert len(groups) == 1 and groups[0]["lr"] == 0.005
            assert len(groups[0]["params"]) == len(list(f.parameters()))


@pytest.mark.parametrize("kind,d", [("cp", 3), ("six_axis", 2), ("vector_matrix", 2)])
def test_product_kinds_closed_form(kind, d):
    f = _constant_magnitude(make(kind))
    scales = step_scales(f)
    assert set(scales) == {f"factors.{n}" for n in f.factors}
    for s in scales.values():
        assert s == pytest.approx(1.0 / math.sqrt(f.rank * d * M ** (2 * (d - 1))), rel=1e-6)


def test_names_follow_named_parameters_in_compositions():
    a, b = make("triplane"), make("cp")
    hybrid = tdfields.Hybrid({"geometry": tdfields.MultiResolution([a, b]), "appearance": make("six_axis")})
    scales = step_scales(hybrid)
    names = {n for n, _ in hybrid.named_parameters()}
    assert set(scales) == names
    assert scales["geometry.levels.0.factors.xy"] == 1.0
    assert scales["geometry.levels.1.factors.x"] > 1.0  # init_std 0.1: a small product, a large scale


def _batch_step(kind, scaled, n=9, rank=2, seed=0):
    """RMS feature change over every grid node after one Adam step on a batch loss with random per-point weights
    (as a rendering loss gives), per term, in units of lr."""
    extra = {"rank": rank} if kind in ("cp", "six_axis", "vector_matrix") else {}
    f = tdfields.build({"kind": kind, "aabb": [[0, 1], [0, 1], [0, 1]], "grid_shape": [n, n, n], "channels": 4,
                        **extra})
    _constant_magnitude(f, seed)
    g = torch.Generator().manual_seed(seed)
    pts = torch.stack(torch.meshgrid(*[torch.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3).float() / (n - 1)
    w = torch.randn(pts.shape[0], 4, generator=g)
    before = f(pts).detach()
    opt = torch.optim.Adam(scaled_param_groups(f, LR, "matched" if scaled else "none"))
    (f(pts) * w).sum().backward()
    opt.step()
    moved = (f(pts).detach() - before).pow(2).mean().sqrt()
    return float(moved) / LR / math.sqrt(len(f.terms()))


@pytest.mark.parametrize("seed", [0, 1])
def test_one_adam_step_moves_every_kind_about_as_far_as_a_plane(seed):
    plane = _batch_step("triplane", True, seed=seed)
    assert plane == pytest.approx(1.0, abs=0.1)
    assert _batch_step("triplane", False, seed=seed) == plane  # scale 1.0: the same step, exactly
    for kind in ("cp", "six_axis", "vector_matrix"):
        assert 0.9 * plane < _batch_step(kind, True, seed=seed) < 1.25 * plane, kind
    # unscaled, rank-2 CP with factors of 0.3 moves at a quarter of a plane's speed
    assert _batch_step("cp", False, seed=seed) < 0.35 * plane


def test_non_finite_factor_is_named():
    f = make("cp")
    with torch.no_grad():
        f.factors["y"][0, 0] = float("nan")
    with pytest.raises(ValueError, match="factors.y"):
        step_scales(f)


def test_zero_product_is_an_error_not_an_infinite_rate():
    f = make("cp")
    with torch.no_grad():
        for p in f.parameters():
            p.zero_()
    with pytest.raises(ValueError, match="all zero"):
        step_scales(f)


def test_lift_raises_slow_products_and_keeps_fast_ones():
    cp = _constant_magnitude(make("cp"))         # rank 3, factors 0.3: scale 1/sqrt(3*3*0.0081) = 3.7
    sa = _constant_magnitude(make("six_axis"))   # rank 3, factors 0.3: scale 1/sqrt(3*2*0.09) = 1.36
    with torch.no_grad():
        for p in sa.parameters():
            p.mul_(3.0)                          # factors 0.9: scale 0.45
    for f, expect in ((cp, 1.0 / math.sqrt(3 * 3 * M ** 4)), (sa, 1.0)):
        for group in scaled_param_groups(f, 0.01, "lift"):
            assert group["lr"] == pytest.approx(0.01 * expect, rel=1e-6)
    for group in scaled_param_groups(sa, 0.01, "matched"):
        assert group["lr"] == pytest.approx(0.01 / math.sqrt(3 * 2 * 0.81), rel=1e-6)
    with pytest.raises(ValueError, match="mode"):
        scaled_param_groups(cp, 0.01, "double")
