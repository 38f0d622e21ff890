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


def test_hybrid_query_all_or_by_name():
    h = hybrid()
    x = torch.rand(5, 3)
    both = h(x)
    assert set(both) == {"geometry", "appearance"}
    assert both["appearance"].shape == (5, 12)
    only = h(x, names=["geometry"])
    assert list(only) == ["geometry"]
    torch.testing.assert_close(only["geometry"], both["geometry"])
    assert h.out_dims == {"geometry": 8, "appearance": 12}
    with pytest.raises(KeyError, match="colour"):
        h["colour"]


def test_report_rows_and_totals():
    h = hybrid()
    model = torch.nn.ModuleDict({"scene": h, "decoder": tdfields.MLPDecoder(8, 1)})
    rep = tdfields.report(model)
    assert [r.name for r in rep.rows] == ["scene.fields.geometry.levels.0", "scene.fields.geometry.levels.1",
                                          "scene.fields.appearance.levels.0", "scene.fields.appearance.levels.1"]
    assert rep.field_parameters == h.num_parameters()
    assert rep.other_parameters == sum(p.numel() for p in model["decoder"].parameters())
    assert rep.total_parameters == sum(p.numel() for p in model.parameters())
    assert rep.parameters_under("scene.fields.geometry") == h["geometry"].num_parameters()
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
