"""benchmarks/frame_breakdown.py at toy size: one run of the tiny room, its time split per frame."""

import json
from pathlib import Path

from tests.benchmarks.conftest import script_on_path
from tests.slam.conftest import TINY, tiny_seq  # noqa: F401 - the tiny room, a fixture

ROOT = Path(__file__).resolve().parents[2]


def test_a_run_splits_its_frame_time(tiny_seq, tmp_path):
    variant = f"now={ROOT}:--config synthetic --data {tiny_seq} --no-mesh parallel=false {' '.join(TINY)}"
    with script_on_path("frame_breakdown") as bench:
        assert bench.main(["--variant", variant, "--repeats", "1", "--out", str(tmp_path)]) == 0
    (run,) = json.loads((tmp_path / "frame_breakdown.json").read_text())["runs"]
    per = run["per_frame"]
    assert per["tracking_s"] > 0 and per["mapping_s"] > 0 and per["loop_s"] >= per["tracking_s"]
    assert "now" in (tmp_path / "frame_breakdown.md").read_text()
