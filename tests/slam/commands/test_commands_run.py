"""``lrslam run``: what is checked before a fresh run starts, and what a resumed run no longer needs."""

import json

import pytest

from tests.slam.conftest import TINY


def test_a_missing_keyframe_spill_dir_stops_only_a_fresh_run_that_would_spill(tiny_seq, tmp_path, capsys):
    """The spill folder is scratch: a run folder moved to another machine, or whose scratch was cleaned, resumes
    (its keyframe images then stay in memory, the same bits) and may name another folder; a fresh run that would
    spill into a folder that is not there stops in one line before any work; one that keeps every keyframe in
    memory never looks at it."""
    from slam.cli import main

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    spill = [f"mapping.keyframe_spill_dir={scratch}", "mapping.keyframes_in_memory=1"]
    run = ["run", "--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--quiet", "--no-mesh"]
    out = tmp_path / "run"
    assert main([*run, "--out", str(out), "--stop-after", "2", *TINY, *spill]) == 0
    capsys.readouterr()
    scratch.rmdir()
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 0
    assert json.loads((out / "metrics.json").read_text())["num_frames"] == 6

    fresh = tmp_path / "fresh"
    assert main([*run, "--out", str(fresh), *TINY, *spill]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"'mapping.keyframe_spill_dir' = '{scratch}' is not a folder" in err[0]
    assert not fresh.exists()  # refused before any work
    assert main([*run, "--out", str(fresh), "--stop-after", "1", *TINY, f"mapping.keyframe_spill_dir={scratch}",
                 "mapping.keyframes_in_memory=0"]) == 0


def test_a_resume_may_name_another_keyframe_spill_dir(tiny_seq, tmp_path):
    """Where scratch files go decides nothing a run computes: ``--resume OUT mapping.keyframe_spill_dir=DIR``."""
    from slam.cli import main
    from slam.config.presets import read_yaml

    old, new = tmp_path / "old", tmp_path / "new"
    old.mkdir()
    new.mkdir()
    out = tmp_path / "run"
    assert main(["run", "--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--quiet", "--no-mesh", "--out", str(out), "--stop-after", "2", *TINY,
                 f"mapping.keyframe_spill_dir={old}", "mapping.keyframes_in_memory=1"]) == 0
    old.rmdir()
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh", f"mapping.keyframe_spill_dir={new}"]) == 0
    assert read_yaml(out / "config.yaml", "run config")["mapping"]["keyframe_spill_dir"] == str(old)


def test_data_alone_detects_the_preset_and_runs_the_devices_default_profile(tiny_seq, tmp_path, capsys):
    """``lrslam run --data DIR``: the kind detected (the tiny room is a Replica folder), its camera read from it, the
    box sized from its first frames, the realtime profile on the CPU; --profile and --config choose otherwise."""
    import yaml

    from slam.cli import main

    out = tmp_path / "run"
    assert main(["run", "--data", str(tiny_seq), "--no-mesh", "--out", str(out), *TINY, "parallel=false"]) == 0
    err = capsys.readouterr().err
    assert f"lrslam run: {tiny_seq}: replica data, profile realtime (choose with --config, --profile)" in err
    assert "far apart" not in err  # a degree or so between the tiny room's frames
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert (cfg["name"], cfg["profile"], cfg["data"]["kind"], cfg["scene"]["bound"]) == ("replica", "realtime",
                                                                                       "replica", "auto")
    assert cfg["tracking"]["optimizer"] == "gauss_newton" and cfg["scene"]["grow_reach"] == "box"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["num_frames"] == 6 and metrics["ate_rmse_m"] < 0.05


def test_a_run_whose_frames_were_far_apart_says_so(tiny_seq, tmp_path, capsys):
    """Every 12th frame of the tiny room (frames 0 and 12, 11.4 degrees apart): the run ends saying how far apart its
    frames were and where the page is that tells what that costs; metrics.json holds the steps (tracked right)."""
    from slam.cli import main

    out = tmp_path / "run"
    assert main(["run", "--data", str(tiny_seq), "--no-mesh", "--quiet", "--out", str(out), "parallel=false",
                 "data.stride=12"]) == 0  # the profile's own budgets: two frames
    steps = json.loads((out / "metrics.json").read_text())["frame_steps"]["turn_deg"]
    assert 10.0 < steps["p95"] < 13.0, steps
    err = capsys.readouterr().err
    assert "the frames taken were far apart" in err and "How far apart the frames can be" in err


def test_the_preset_of_a_data_folder_is_its_detected_kind(tiny_seq, tmp_path, shared_data):
    import pytest

    from slam.commands.run import data_preset
    from slam.errors import SlamInputError

    assert data_preset(str(tiny_seq)) == "replica"
    assert data_preset(str(shared_data / "tum_fr1_rpy")) == "tum"
    (tmp_path / "notes.txt").write_text("not a dataset")
    with pytest.raises(SlamInputError, match="not a recognised dataset layout"):
        data_preset(str(tmp_path))
    with pytest.raises(SlamInputError, match="not found"):
        data_preset(str(tmp_path / "missing"))


def test_every_detected_dataset_kind_has_its_preset():
    """``lrslam run --data DIR`` runs the preset named after the detected kind: every kind a probe detects has one."""
    from slam.config import load_config
    from slam.config.presets import CONFIG_DIR
    from slam.data import DATASETS

    for name, kind in DATASETS.items():
        if kind.looks_like is not None:
            assert (CONFIG_DIR / f"{name}.yaml").is_file(), name
            assert load_config(name).data.kind == name


def test_overrides_go_before_between_and_after_the_options():
    """``lrslam run a=1 --no-mesh b=2``: argparse alone takes one run of positionals and stopped at ``b=2``."""
    from slam.cli import _parse, build_parser

    parser = build_parser()
    args = _parse(parser, ["run", "seed=1", "--no-mesh", "mapping.iters=5", "--quiet", "seed=2"])
    assert args.overrides == ["seed=1", "mapping.iters=5", "seed=2"] and args.no_mesh and args.quiet
    assert _parse(parser, ["params", "representation=eslam", "--config", "tum", "x=1"]).overrides == \
        ["representation=eslam", "x=1"]
    with pytest.raises(SystemExit):
        _parse(parser, ["run", "--no-mesj"])  # a mistyped option is still an error
