"""benchmarks/memory_rss.py at toy size: one run of the tiny room sampled every 2 frames, and its table row."""

import json

from tests.benchmarks.conftest import script_on_path
from tests.slam.conftest import tiny_seq  # noqa: F401 - the tiny room, a fixture


def test_a_run_samples_resident_memory_and_its_parts(tiny_seq, tmp_path):
    out = tmp_path / "run.json"
    with script_on_path("memory_rss") as bench:
        bench.run_one("synthetic", "after", str(tiny_seq), 4, 2, 2, str(out))
        rec = json.loads(out.read_text())
        text = bench.table([rec], {"date": "d", "tdfields_version": "v", "torch_version": "t", "cpu": "c",
                                   "torch_threads": 1, "device": "cpu"}, "toy")
    assert [p["frame"] for p in rec["series"]][:2] == [0, 2]
    last = rec["series"][-1]
    assert last["rss_mb"] >= last["base_mb"] > 0 and last["scene_mb"] > 0 and last["keyframes"] >= 1
    assert "| synthetic | after |" in text
