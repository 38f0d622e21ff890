"""``lrslam run``: what is checked before a fresh run starts, and what a resumed run no longer needs."""

import json

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
