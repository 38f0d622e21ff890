import pytest
import torch

import tdfields

BOX = [[0, 1], [0, 1], [0, 1]]


def test_build_each_kind_from_dict():
    for kind, cls in tdfields.KINDS.items():
        spec = {"kind": kind, "aabb": BOX, "cell_size": 0.25, "channels": 3}
        if cls.has_rank:
            spec["rank"] = 2
        f = tdfields.build(spec)
        assert isinstance(f, cls) and f.grid_shape == (4, 4, 4)


def test_multires_shorthand_and_levels():
    a = tdfields.build({"kind": "cp", "aabb": BOX, "cell_size": [0.5, 0.1], "channels": 4, "rank": 2})
    b = tdfields.build({"kind": "multires", "levels": [
        {"kind": "cp", "aabb": BOX, "cell_size": 0.5, "channels": 4, "rank": 2},
        {"kind": "cp", "aabb": BOX, "cell_size": 0.1, "channels": 4, "rank": 2}]})
    for m in (a, b):
        assert isinstance(m, tdfields.MultiResolution)
        assert m.out_dim == 8
        assert [lv.grid_shape for lv in m.levels] == [(2, 2, 2), (10, 10, 10)]


def test_yaml_file(tmp_path):
    p = tmp_path / "field.yaml"
    p.write_text("kind: six_axis\naabb: [[0, 1], [0, 2], [0, 1]]\ncell_size: 0.1\nchannels: 8\nrank: 4\n")
    f = tdfields.build(p)
    assert isinstance(f, tdfields.SixAxis) and f.grid_shape == (10, 20, 10)


@pytest.mark.parametrize("spec, match", [
    ({"kind": "cp", "aabb": BOX, "cell_size": 0.1, "channels": 4, "rank": 2, "colour": 1}, "colour"),
    ({"kind": "octree", "aabb": BOX, "cell_size": 0.1, "channels": 4}, "octree"),
    ({"kind": "cp", "cell_size": 0.1, "channels": 4, "rank": 2}, "aabb"),
    ({"kind": "triplane", "aabb": BOX, "cell_size": 0.1, "channels": 4, "rank": 2}, "rank"),
    ({"kind": "multires", "levels": []}, "levels"),
    ({"kind": "hybrid", "fields": {"g": {"kind": "cp", "aabb": BOX, "cell_size": 0.1, "channels": 4, "rank": 2,
                                         "bogus": 0}}}, r"fields\.g.*bogus"),
])
def test_bad_specs_name_the_key(spec, match):
    with pytest.raises(ValueError, match=match):
        tdfields.build(spec)


def test_bad_yaml_names_file(tmp_path):
    p = tmp_path / "f.yaml"
    p.write_text("kind: cp\naabb: [[0, 1], [0, 1], [0, 1]]\ncell_size: 0.1\nchannels: 4\nrank: 2\ntypo: 3\n")
    with pytest.raises(ValueError, match=r"f\.yaml.*typo"):
        tdfields.build(p)
    with pytest.raises(FileNotFoundError, match="missing.yaml"):
        tdfields.build(tmp_path / "missing.yaml")


def test_spec_roundtrip_rebuilds_same_shapes():
    f = tdfields.build({"kind": "six_axis", "aabb": BOX, "cell_size": 0.2, "channels": 3, "rank": 2})
    g = tdfields.build(f.spec())
    assert g.grid_shape == f.grid_shape and g.num_parameters() == f.num_parameters()
    g.load_state_dict(f.state_dict())
    x = torch.rand(5, 3)
    torch.testing.assert_close(f(x), g(x))
