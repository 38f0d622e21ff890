import pytest
import torch

import tdfields

BOX = [[0, 1], [0, 1], [0, 1]]


def hybrid():
    torch.manual_seed(0)
    return tdfields.build({"kind": "hybrid", "fields": {
        "geometry": {"kind": "cp", "aabb": BOX, "cell_size": [0.5, 0.1], "channels": 4, "rank": 2},
        "appearance": {"kind": "six_axis", "aabb": BOX, "cell_size": [0.5, 0.05], "channels": 6, "rank": 3},
    }})


def test_multires_concatenates_levels_in_order():
    m = hybrid()["geometry"]
    x = torch.rand(2, 7, 3)
    out = m(x)
    assert out.shape == (2, 7, 8)
    torch.testing.assert_close(out[..., :4], m.levels[0](x))
    torch.testing.assert_close(out[..., 4:], m.levels[1](x))
    assert m.complexity == "O(n)" and m.grid_shape == (10, 10, 10)
    assert m.num_parameters() == m.closed_form_parameters()


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_nested_multires_plans_natively_from_its_levels(backend):
    """A stack inside a stack is planned from its levels too: one program over every grid, the query its plan."""
    torch.manual_seed(0)
    inner = tdfields.MultiResolution([tdfields.TriPlane(BOX, grid_shape=(4, 5, 6), channels=2),
                                      tdfields.SixAxis(BOX, grid_shape=(9, 8, 7), channels=3, rank=2)])
    m = tdfields.MultiResolution([tdfields.CP(BOX, grid_shape=(5, 5, 5), channels=4, rank=2), inner]).double()
    x = torch.rand(300, 3, dtype=torch.float64)
    with tdfields.kernels.use_backend(backend):
        plan = tdfields.plan(m, x)
        out = m(x)
        assert torch.equal(out, tdfields.ops.evaluate(plan.program, plan.tensors, plan.coords))
        parts = [level(x) for level in m.levels]
    assert [g[1] for g in m.grids()] == [(5, 5, 5), (4, 5, 6), (9, 8, 7)]
    assert plan.program.num_levels == 3 and plan.coords.shape == (3, 300, 3) and out.shape == (300, 9)
    # the reference is exact; a fused kernel compiled for the whole program rounds as another fastmath build may
    exact = {"rtol": 0, "atol": 0} if backend == "torch" else {}
    torch.testing.assert_close(out, torch.cat(parts, -1), **exact)
    with pytest.raises(AttributeError):  # a Plan is frozen
        plan.coords = plan.coords * 2


def test_hybrid_query_all_or_by_name():
    h = hybrid()
    x = torch.rand(5, 3)
    both = h(x)
    assert set(both) == {"geometry", "appearance"}
    assert both["appearance"].shape == (5, 12)
    only = h(x, names=["geometry"])
    assert list(only) == ["geometry"]
    torch.testing.assert_close(only["geometry"], both["geometry"])
    assert h.names() == ["geometry", "appearance"] and "geometry" in h and "colour" not in h
    with pytest.raises(KeyError, match="colour"):
        h["colour"]


def test_hybrid_parameter_names_read_as_the_nesting():
    names = list(hybrid().state_dict())
    assert names[:2] == ["geometry.levels.0.aabb", "geometry.levels.0.factors.x"] and "appearance.levels.1.factors.zx_x" in names
    with pytest.raises(ValueError, match="'spec' is taken"):
        tdfields.Hybrid({"spec": hybrid()["geometry"]})


def test_hybrid_loads_state_dicts_with_the_old_fields_prefix():
    """State dicts saved when Hybrid kept its fields in a ``fields`` ModuleDict, alone or inside a model."""
    source, target = hybrid(), hybrid()
    for p in target.parameters():
        torch.nn.init.zeros_(p)
    old = {f"fields.{k}": v for k, v in source.state_dict().items()}
    target.load_state_dict(old)  # strict: every key mapped, none left over
    for (name, a), b in zip(source.state_dict().items(), target.state_dict().values()):
        assert torch.equal(a, b), name
    outer, outer2 = torch.nn.ModuleDict({"scene": source}), torch.nn.ModuleDict({"scene": hybrid()})
    outer2.load_state_dict({f"scene.fields.{k}": v for k, v in source.state_dict().items()})
    assert all(torch.equal(a, b) for a, b in zip(outer.state_dict().values(), outer2.state_dict().values()))
    with pytest.raises(RuntimeError, match="Unexpected key"):
        target.load_state_dict({**old, "fields.colour.x": torch.zeros(1)})


def test_report_rows_and_totals():
    h = hybrid()
    model = torch.nn.ModuleDict({"scene": h, "decoder": tdfields.MLPDecoder(8, 1)})
    rep = tdfields.report(model)
    assert [r.name for r in rep.rows] == ["scene.geometry.levels.0", "scene.geometry.levels.1",
                                          "scene.appearance.levels.0", "scene.appearance.levels.1"]
    assert rep.field_parameters == h.num_parameters()
    assert rep.other_parameters == sum(p.numel() for p in model["decoder"].parameters())
    assert rep.total_parameters == sum(p.numel() for p in model.parameters())
    assert rep.parameters_under("scene.geometry") == h["geometry"].num_parameters()
    assert rep.total_bytes == 4 * rep.total_parameters
    d = rep.as_dict()
    assert d["fields"][0]["kind"] == "cp" and d["fields"][3]["rank"] == 3
    table = str(rep)
    assert "six_axis" in table and "O(n)" in table and f"{rep.total_parameters:,}" in table


def test_decoder_shapes_and_activation():
    d = tdfields.MLPDecoder(6, 3, hidden=5, output_activation="sigmoid")
    y = d(torch.randn(2, 4, 6) * 100)
    assert y.shape == (2, 4, 3) and (y >= 0).all() and (y <= 1).all()
    with pytest.raises(ValueError, match="output_activation"):
        tdfields.MLPDecoder(6, 3, output_activation="gelu6")
