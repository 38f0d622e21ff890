"""benchmarks/realtime_replay.py at toy size: a real-time run of the tiny room per seed, its counts and summary."""

import json

from tests.benchmarks.conftest import load_script
from tests.slam.conftest import TINY, tiny_seq  # noqa: F401 - the tiny room, a fixture


def test_it_records_each_seeds_counts_and_their_mean(tiny_seq, tmp_path):
    bench = load_script("realtime_replay")
    out = tmp_path / "rt.json"
    assert bench.main(["--config", "synthetic", "--data", str(tiny_seq), "--seeds", "1", "--out", str(out),
                       "--set", *TINY]) == 0
    doc = json.loads(out.read_text())
    runs = doc["sequences"][tiny_seq.name]["runs"]
    assert [r["seed"] for r in runs] == [0] and doc["stamp"]["cpu"]
    for r in runs:  # 6 frames offered at 30 Hz: every one processed or dropped, the first and last always taken
        assert r["frames_processed"] + r["frames_dropped"] == 6 and r["frames_processed"] >= 2
        assert r["latency_median_s"] > 0 and r["ate_rmse_cm"] is not None
        # the tiny room's steps are small: no frame needs a wider ICP start; the warm-up's odometry is counted
        assert r["wide_starts"] == 0 and 0 <= r["frames_odometry"] < r["frames_processed"]
    s = doc["sequences"][tiny_seq.name]["summary"]
    assert s["frames_processed"] == {"mean": runs[0]["frames_processed"], "std": 0.0}
