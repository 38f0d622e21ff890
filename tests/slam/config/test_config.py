import pytest

from slam.config import list_presets, load_config, parse_overrides
from slam.errors import SlamInputError


def test_presets_exist_and_resolve():
    names = list_presets()
    for name in ("synthetic", "synthetic/walk", "replica", "replica/room0", "scannet/scene0000", "tum/fr1_desk",
                 "tum/fr1_rpy", "7scenes", "bag"):
        assert name in names
        cfg = load_config(name)
        assert cfg.name == name and cfg.profile == "realtime"
    assert not any(name.startswith("profiles/") for name in names)


def test_layering_base_dataset_scene():
    cfg = load_config("tum/fr1_desk", profile="paper")
    assert cfg.tracking.iters == 200 and cfg.tracking.lr_t == 0.01  # dataset layer
    assert cfg.scene.bound == [[-4.6, 2.6], [-3.3, 3.2], [-2.0, 4.9]]  # scene layer
    assert cfg.mapping.lr_decoders == 0.001  # base
    assert cfg.geometry.kind == "cp" and cfg.geometry.rank == 2
    assert cfg.appearance.kind == "six_axis" and cfg.appearance.rank == 16
    assert cfg.geometry.cell_sizes == [0.24, 0.06] and cfg.appearance.cell_sizes == [0.24, 0.03]


def test_representation_switch_and_overrides():
    cfg = load_config("replica/room0", ["representation=eslam", "tracking.iters=3", "bound=auto"], profile="paper")
    assert cfg.geometry.kind == "triplane" and cfg.appearance.kind == "triplane"
    assert cfg.tracking.iters == 3 and cfg.scene.bound == "auto"
    cfg = load_config("replica/room0", ["representation=cp_cp", "appearance.rank=4"], profile="paper")
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
        ("synthetic", ["mapping.optimizer_state=kept"], "'mapping.optimizer_state' = 'kept' is not allowed"),
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
    assert load_config("synthetic", ["rendering.color_cutoff=0"], profile="quality").rendering.color_cutoff == 0.0
    with pytest.raises(SlamInputError, match="color_cutoff"):
        load_config("synthetic", ["rendering.color_cutoff=-0.1"], profile="quality")


def test_exponent_notation_is_a_number():
    """YAML 1.1 reads '1e-3' (no dot) as a string; a float key takes it as the number, other strings still fail."""
    assert load_config("synthetic", ["rendering.color_cutoff=1e-3"], profile="quality").rendering.color_cutoff == 1e-3
    assert load_config("synthetic", ["mapping.lr_geometry=5E-3"], profile="quality").mapping.lr_geometry == 5e-3
    with pytest.raises(SlamInputError, match="mapping.lr_geometry"):
        load_config("synthetic", ["mapping.lr_geometry=1e"], profile="quality")
    with pytest.raises(SlamInputError, match="keep_freed_memory"):
        load_config("synthetic", ["keep_freed_memory=maybe"], profile="quality")


def _numeric_keys(cls=None, prefix=""):
    """Every int / float / list-of-number key of the config tree with its dataclass field."""
    import dataclasses
    from typing import get_type_hints

    from slam.config import Config
    from slam.core.losses import LossWeights

    cls = cls or Config
    hints = get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            yield from _numeric_keys(tp, prefix + f.name + ".")
        elif cls is LossWeights or any(t in str(tp) for t in ("int", "float")) or f.name in (
                "cell_sizes", "ignore_edge"):
            yield prefix + f.name, f


def test_every_numeric_key_declares_a_range():
    from slam.core.losses import LossWeights

    missing = [k for k, f in _numeric_keys() if "range" not in f.metadata and not k.split(".")[-1] in
               LossWeights.__dataclass_fields__]
    assert missing == []
    # and an upper bound: a value no run can use (1e30 pixels) is refused as the config is read, not mid-run
    unbounded = [k for k, f in _numeric_keys() if "range" in f.metadata and f.metadata["range"].hi is None]
    assert unbounded == []


def _bad_value(key, rng):
    if rng.lo is not None:
        v = rng.lo - 1 if not rng.lo_open else rng.lo
    else:
        v = rng.hi + 1
    return [v, v] if key.endswith(("cell_sizes", "ignore_edge")) else v


def test_icp_normals_must_be_an_odd_square():
    # an even square has no centre pixel: the reference's pooling would change the image's size
    assert load_config("synthetic", ["tracking.icp_normals=5"]).tracking.icp_normals == 5
    with pytest.raises(SlamInputError, match=r"config key 'tracking.icp_normals' = 4 must be odd"):
        load_config("synthetic", ["tracking.icp_normals=4"])


@pytest.mark.parametrize("key", [k for k, _ in _numeric_keys()])
def test_out_of_range_values_name_key_value_and_range(key):
    from slam.config import Range

    f = dict(_numeric_keys())[key]
    rng = f.metadata.get("range", Range(0))
    bad = _bad_value(key, rng)
    with pytest.raises(SlamInputError, match=rf"config key '{key}' = .* is out of range: must be"):
        load_config("synthetic", [f"{key}={bad}"], profile="quality")
    # the values a user (or a script's bug) types: never accepted, never a traceback, always one line naming the key
    for odd in (".inf", "-.inf", ".nan", "-1", "1e30", "1.0e+300"):
        value = f"[{odd}, {odd}]" if key.endswith(("cell_sizes", "ignore_edge")) else odd
        with pytest.raises(SlamInputError, match=rf"config key '{key}'") as info:
            load_config("synthetic", [f"{key}={value}"], profile="quality")
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("n", [1, 2])
def test_max_keyframes_below_three_breaks_the_keep_first_and_last_two_rule(n):
    with pytest.raises(SlamInputError, match="'mapping.max_keyframes' = .* must be 0 .* or >= 3"):
        load_config("synthetic", [f"mapping.max_keyframes={n}"], profile="quality")
    assert load_config("synthetic", ["mapping.max_keyframes=3"], profile="quality").mapping.max_keyframes == 3


def test_keyframe_spill_dir_is_checked_where_a_fresh_run_starts_not_when_a_config_is_read(tmp_path):
    """A run folder's config is read where its scratch folder is never used (lrslam mesh, a resume on another
    machine): only a fresh run that will spill needs it (tests/slam/commands/test_commands_run.py)."""
    from slam.engine.setup import check_spill_dir

    missing = tmp_path / "no such dir"
    (tmp_path / "a file").write_text("")
    for spill in (missing, tmp_path / "a file"):
        cfg = load_config("synthetic", [f"mapping.keyframe_spill_dir={spill}"], profile="quality")
        assert cfg.mapping.keyframe_spill_dir == str(spill)
        with pytest.raises(SlamInputError, match=r"'mapping.keyframe_spill_dir' = .* is not a folder \(keyframe"):
            check_spill_dir(cfg)
        check_spill_dir(load_config("synthetic", [f"mapping.keyframe_spill_dir={spill}",
                                                  "mapping.keyframes_in_memory=0"], profile="quality"))  # never spills
    check_spill_dir(load_config("synthetic", [f"mapping.keyframe_spill_dir={tmp_path}"], profile="quality"))


def test_ignore_edge_must_leave_pixels_in_the_working_image(tiny_seq, capsys):
    from slam.cli import main

    # the tiny sequence is 60 x 80: 30 rows off each side leave none
    assert main(["run", "--data", str(tiny_seq), "--no-mesh", "--quiet", "tracking.ignore_edge=[30, 10]"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("lrslam run: error: config key 'tracking.ignore_edge' = [30, 10] leaves no pixel")


def test_moved_keys_say_where_they_went():
    with pytest.raises(SlamInputError, match="'meshing.eval_samples' is now 'evaluation.samples'"):
        load_config("synthetic", ["meshing.eval_samples=10"], profile="quality")


def test_cli_exits_2_with_one_line_for_a_bad_value(capsys):
    from slam.cli import main

    assert main(["run", "tracking.iters=0", "--no-mesh"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["lrslam run: error: config key 'tracking.iters' = 0 is out of range: must be >= 1 and <= 10000000"]


def test_saved_config_reloads_identically(tmp_path):
    from slam.config import config_from_dict, save_config

    import yaml

    cfg = load_config("tum/fr1_rpy-cpu", ["seed=3", "representation=eslam"])
    save_config(cfg, tmp_path / "config.yaml")
    assert config_from_dict(yaml.safe_load((tmp_path / "config.yaml").read_text())) == cfg


def test_configs_written_by_older_versions_are_upgraded():
    from slam.config import config_from_dict

    old = load_config("synthetic", profile="quality").to_dict()
    old["meshing"].update(eval_samples=1234, eval_icp=False, depth_l1_views=7)
    del old["evaluation"]
    cfg = config_from_dict(old, upgrade=True)
    assert (cfg.evaluation.samples, cfg.evaluation.icp, cfg.evaluation.depth_l1_views) == (1234, False, 7)
    with pytest.raises(SlamInputError, match="is now 'evaluation.samples'"):
        config_from_dict(old)


def test_a_partial_nested_override_keeps_the_other_defaults():
    cfg = load_config("synthetic", ["tracking.weights.fs=0", "mapping.weights.color=2"], profile="quality")
    assert (cfg.tracking.weights.fs, cfg.tracking.weights.center, cfg.tracking.weights.tail) == (0.0, 200.0, 50.0)
    assert (cfg.mapping.weights.color, cfg.mapping.weights.fs, cfg.mapping.weights.depth) == (2.0, 5.0, 0.1)
