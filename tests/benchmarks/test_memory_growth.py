"""benchmarks/memory_growth.py at toy size: two kinds at two scene sizes, their parameters and fitted slopes."""

import json

from tests.benchmarks.conftest import script_on_path


def test_cp_grows_linearly_and_planes_quadratically_in_parameters(tmp_path):
    from tdfields import kernels

    before = kernels.get_backend()  # the script sets the process's backend (a command line's whole process)
    with script_on_path("memory_growth") as bench:
        try:
            assert bench.main(["--kinds", "cp", "triplane", "--min-side", "1", "--max-side", "4", "--sizes", "2",
                                   "--cell", "0.1", "--points", "256", "--steps", "1", "--fit-last", "2",
                                   "--out", str(tmp_path)]) == 0
        finally:
            kernels.set_backend(before)
    doc = json.loads((tmp_path / "memory_growth.json").read_text())
    assert {r["kind"] for r in doc["rows"]} == {"cp", "triplane"}
    # parameters are closed forms: a line per axis for CP (slope 1), planes for the tri-plane (slope 2)
    assert abs(doc["exponents"]["cp"]["parameters"] - 1) < 0.1
    assert abs(doc["exponents"]["triplane"]["parameters"] - 2) < 0.1
    assert (tmp_path / "memory_growth.png").stat().st_size > 0
