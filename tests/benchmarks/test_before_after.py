"""benchmarks/before_after.py (shared by frame_breakdown.py): a variant's relative paths mean what they meant where
the command was typed, though every run starts in its own checkout."""

import json
from pathlib import Path

import pytest

from tests.benchmarks.conftest import load_script
from tests.slam.conftest import tiny_seq  # noqa: F401 - the tiny room, a fixture

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def before_after():
    return load_script("before_after")


def test_relative_data_and_config_paths_are_made_absolute_preset_names_kept(before_after, tmp_path, monkeypatch):
    (tmp_path / "seq").mkdir()
    (tmp_path / "my.yaml").write_text("inherit: synthetic\n")
    monkeypatch.chdir(tmp_path)
    v = before_after.parse_variant(f"a={ROOT}:--config my.yaml --data seq --no-mesh seed=3")
    assert v["args"] == ["--config", str(tmp_path / "my.yaml"), "--data", str(tmp_path / "seq"), "--no-mesh",
                         "seed=3"]
    v = before_after.parse_variant(f"b={ROOT}:--config tum/fr1_rpy-cpu --data missing")
    assert v["args"] == ["--config", "tum/fr1_rpy-cpu", "--data", "missing"]  # not paths here: the run says so
    assert v["checkout"] == str(ROOT)


def test_a_variant_that_is_not_a_checkout_is_a_usage_error(before_after, tmp_path):
    with pytest.raises(SystemExit, match="not a checkout of this project"):
        before_after.parse_variant(f"a={tmp_path}:--no-mesh")
    with pytest.raises(SystemExit, match="NAME=CHECKOUT:ARGS"):
        before_after.parse_variant("no-equals-sign")


def test_a_toy_run_times_each_variant_and_tables_it(tiny_seq, tmp_path):
    """Two interleaved repeats of this checkout on the tiny room: the JSON holds both runs and their median."""
    from tests.slam.conftest import TINY

    bench = load_script("before_after")
    variant = f"now={ROOT}:--config synthetic --data {tiny_seq} --no-mesh parallel=false {' '.join(TINY)}"
    assert bench.main(["--variant", variant, "--repeats", "2", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "before_after.json").read_text())
    (row,) = doc["rows"]
    assert len(doc["runs"]) == 2 and row["fpt_s"] == pytest.approx(sorted(row["fpt_runs_s"])[0], abs=1e-3) or \
        min(row["fpt_runs_s"]) <= row["fpt_s"] <= max(row["fpt_runs_s"])
    assert "now" in (tmp_path / "before_after.md").read_text()
