"""benchmarks/profile_targets.py at toy size: the default and the references on the room, per seed, and the table."""

import json

from tests.benchmarks.conftest import script_on_path
from tests.slam.conftest import TINY

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


def test_it_runs_the_default_and_each_reference_per_seed_and_tables_them(tmp_path):
    with script_on_path("profile_targets") as bench:
        assert bench.main(["--before", str(ROOT), "--after", str(ROOT), "--seeds", "1", "--sequences", "room",
                           "--out", str(tmp_path), "--set", *TINY, "data.max_frames=4"]) == 0
    doc = json.loads((tmp_path / "profile_targets.json").read_text())
    room = doc["sequences"]["room"]
    assert room["frames"] == 4 and set(room["references"]) == {"quality", "own"}
    for summary in (room["default"], *room["references"].values()):
        assert summary["failed"] == 0 and summary["fpt_s"] > 0 and len(summary["ate_cm"]) == 1
    cfg = (tmp_path / "runs" / "room-default-s0-r0" / "config.yaml").read_text()
    assert "profile: realtime" in cfg and "mapping.every_frame=1" in " ".join(room["args"]["quality"])
    table = (tmp_path / "profile_targets.md").read_text()
    assert "| room | 4 |" in table and "| room (against its own preset) | 4 |" in table
    with script_on_path("profile_targets") as bench:  # the table again from the JSON
        assert bench.main(["--before", str(ROOT), "--out", str(tmp_path), "--table-only"]) == 0
    assert (tmp_path / "profile_targets.md").read_text() == table


def test_loops_runs_the_default_without_and_with_loop_closure_and_tables_both(tmp_path):
    import pytest
    import yaml

    pytest.importorskip("cv2")
    pytest.importorskip("gtsam")
    loops = ["loops.keyframe_distance=0.02", "loops.keyframe_angle=1", "loops.min_gap_frames=6",
             "loops.vocabulary_after=2", "loops.words=8"]
    with script_on_path("profile_targets") as bench:
        assert bench.main(["--loops", "--seeds", "1", "--sequences", "room", "--out", str(tmp_path),
                           "--set", *TINY, "data.max_frames=16", *loops]) == 0
    doc = json.loads((tmp_path / "profile_targets.json").read_text())
    room = doc["sequences"]["room"]
    assert doc["loops"] and set(room["references"]) == {"loops"} and "loops" not in room["default"]
    with_loops = room["references"]["loops"]
    assert with_loops["loops"][0] >= 1 and with_loops["loop_candidates"][0] >= with_loops["loops"][0]
    assert 0 <= with_loops["loop_gt_error_max"][0] < 0.05  # metres: the tiny room's loops are true ones
    for variant, enabled in (("default", False), ("loops", True)):
        cfg = yaml.safe_load((tmp_path / "runs" / f"room-{variant}-s0-r0" / "config.yaml").read_text())
        assert cfg["loops"]["enabled"] is enabled
    table = (tmp_path / "profile_targets.md").read_text()
    assert "| room | 16 |" in table and "worst loop against ground truth" in table
