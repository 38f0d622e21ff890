"""benchmarks/same_trajectories.py at toy size: the hash of a 2-frame room run, equal to itself, and a changed hash
fails the comparison."""

import json

from tests.benchmarks.conftest import script_on_path


def test_hashes_compare_equal_to_themselves_and_a_change_is_caught(tmp_path):
    first, tampered = tmp_path / "a.json", tmp_path / "b.json"
    args = ["--sequences", "synthetic", "--modes", "serial", "--frames", "2"]
    with script_on_path("same_trajectories") as bench:
        assert bench.main([*args, "--out", str(first)]) == 0
        doc = json.loads(first.read_text())
        assert list(doc["hashes"]) == ["synthetic/serial"] and len(doc["hashes"]["synthetic/serial"]) == 64
        doc["hashes"]["synthetic/serial"] = "0" * 64
        tampered.write_text(json.dumps(doc))
        assert bench.main([*args, "--out", str(tmp_path / "c.json"), "--against", str(tampered)]) == 1
    # the second run wrote the first's hash: a run is deterministic for its seed, the premise of the comparison
    assert json.loads((tmp_path / "c.json").read_text())["hashes"] == json.loads(first.read_text())["hashes"]
