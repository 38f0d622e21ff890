"""benchmarks/field_speed_table.py on the committed pytest-benchmark JSON (the toy run is CI's gpu_check smoke)."""

from tests.benchmarks.conftest import BENCHMARKS, script_on_path


def test_the_table_has_a_row_per_case_and_the_ratios(capsys):
    with script_on_path("field_speed_table") as bench:
        assert bench.main([str(BENCHMARKS / "results" / "field_speed.json"), "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "| geometry/lrslam-cp | fused |" in out and "| ratio | forward | forward+backward |" in out
    assert "1 thread(s)" in out


def test_a_missing_file_is_a_clear_error(tmp_path, capsys):
    with script_on_path("field_speed_table") as bench:
        assert bench.main([str(tmp_path / "none.json")]) == 2
    assert "no such file" in capsys.readouterr().err
