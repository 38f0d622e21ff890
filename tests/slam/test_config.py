import pytest

from slam.config import list_presets, load_config, parse_overrides
from slam.errors import SlamInputError


def test_presets_exist_and_resolve():
    names = list_presets()
    for name in ("synthetic", "replica/room0", "scannet/scene0000", "tum/fr1_desk", "tum/fr1_rpy",
                 "tum/fr1_rpy-cpu"):
        assert name in names
        cfg = load_config(name)
        assert cfg.name == name


def test_layering_base_dataset_scene():
    cfg = load_config("tum/fr1_desk")
    assert cfg.tracking.iters == 200 and cfg.tracking.lr_t == 0.01  # dataset layer
    assert cfg.scene.bound == [[-4.6, 2.6], [-3.3, 3.2], [-2.0, 4.9]]  # scene layer
    assert cfg.mapping.lr_decoders == 0.001  # base
    assert cfg.geometry.kind == "cp" and cfg.geometry.rank == 2
    assert cfg.appearance.kind == "six_axis" and cfg.appearance.rank == 16
    assert cfg.geometry.cell_sizes == [0.24, 0.06] and cfg.appearance.cell_sizes == [0.24, 0.03]


def test_representation_switch_and_overrides():
    cfg = load_config("replica/room0", ["representation=eslam", "tracking.iters=3", "bound=auto"])
    assert cfg.geometry.kind == "triplane" and cfg.appearance.kind == "triplane"
    assert cfg.tracking.iters == 3 and cfg.scene.bound == "auto"
    cfg = load_config("replica/room0", ["representation=cp_cp", "appearance.rank=4"])
    assert cfg.appearance.kind == "cp" and cfg.appearance.rank == 4


def test_parse_overrides_types():
    o = parse_overrides(["a.b=1", "c=[1, 2]", "d=true", "e=hello"])
    assert o == {"a": {"b": 1}, "c": [1, 2], "d": True, "e": "hello"}


@pytest.mark.parametrize(
    "preset,overrides,needle",
    [
        ("nope", [], "unknown preset 'nope'"),
        ("synthetic", ["tracking.itres=3"], "tracking.itres"),
        ("synthetic", ["bogus=1"], "bogus"),
        ("synthetic", ["representation=foo"], "unknown representation 'foo'"),
        ("synthetic", ["tracking.iters=abc"], "tracking.iters"),
        ("synthetic", ["noequals"], "key=value"),
        ("missing.yaml", [], "missing.yaml"),
    ],
)
def test_bad_input_names_the_problem(preset, overrides, needle):
    with pytest.raises(SlamInputError, match=needle.replace("[", r"\[")):
        load_config(preset, overrides)


def test_yaml_file_preset(tmp_path):
    p = tmp_path / "mine.yaml"
    p.write_text("inherit: tum/fr1_desk\ntracking: {iters: 7}\n")
    cfg = load_config(str(p))
    assert cfg.tracking.iters == 7 and cfg.scene.bound[0] == [-4.6, 2.6]


def test_color_cutoff_is_validated():
    assert load_config("synthetic", ["rendering.color_cutoff=0"]).rendering.color_cutoff == 0.0
    with pytest.raises(SlamInputError, match="color_cutoff"):
        load_config("synthetic", ["rendering.color_cutoff=-0.1"])


def test_exponent_notation_is_a_number():
    """YAML 1.1 reads '1e-3' (no dot) as a string; a float key takes it as the number, other strings still fail."""
    assert load_config("synthetic", ["rendering.color_cutoff=1e-3"]).rendering.color_cutoff == 1e-3
    assert load_config("synthetic", ["mapping.lr_geometry=5E-3"]).mapping.lr_geometry == 5e-3
    with pytest.raises(SlamInputError, match="mapping.lr_geometry"):
        load_config("synthetic", ["mapping.lr_geometry=1e"])
    with pytest.raises(SlamInputError, match="keep_freed_memory"):
        load_config("synthetic", ["keep_freed_memory=maybe"])
