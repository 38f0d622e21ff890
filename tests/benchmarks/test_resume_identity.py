"""benchmarks/resume_identity.py at toy size: the tiny room stopped by SIGINT after frame 2 and resumed ends with
the uninterrupted run's trajectory, byte for byte."""

import json

from tests.benchmarks.conftest import script_on_path
from tests.slam.conftest import TINY, tiny_seq  # noqa: F401 - the tiny room, a fixture


def test_a_resumed_run_writes_the_uninterrupted_trajectory(tiny_seq, tmp_path, monkeypatch):
    with script_on_path("resume_identity") as bench:
        rc = bench.main(["--config", "synthetic", "--data", str(tiny_seq), "--seeds", "1", "--modes", "sequential",
                         "--at", "2", "--set", *TINY, "--out", str(tmp_path)])
    doc = json.loads((tmp_path / "slam_compare.json").read_text())
    (run,) = doc["sequential_runs"]
    assert rc == 0 and doc["all_identical"] and run["identical"]
    assert run["interrupted_after"] == 2 and run["resumed_from"] == 3 and run["num_frames"] == 6
