"""benchmarks/nerf_encodings.py at toy sizes, tdfields only (nerfstudio is not part of the test environment): the
measuring functions and ``main`` write every field of the JSON with sane values, and the parameter counts are the
kinds' closed forms at the sizes matched to nerfstudio's constructor arguments."""

import json
import math

import pytest
import torch

import tdfields
from tests.benchmarks.conftest import load_script

R, C = 6, 2
TOY_SPEED = {
    "cp": {"field": ("cp", {"resolution": R, "channels": C})},
    "triplane": {"field": ("triplane", {"resolution": R, "channels": C})},
    "vector_matrix": {"field": ("vector_matrix", {"resolution": R, "channels": C})},
    "six_axis": {"field": ("six_axis", {"resolution": R, "channels": C})},
    "multires": {"field": ("multires", {"levels": 2, "min_res": 3, "max_res": 5, "features": C})},
    "hybrid": {"density": ("cp", {"resolution": R, "channels": C}),
               "appearance": ("six_axis", {"resolution": R, "channels": C})},
}
TOY_PSNR = {name: {"density": parts[next(iter(parts))], "appearance": parts[next(iter(parts))]}
            for name, parts in TOY_SPEED.items()}
TOY_PSNR["hybrid"] = TOY_SPEED["hybrid"]
# nerfstudio's parameter counts at the matched arguments: what the tdfields side must equal (the hash grid: its
# tri-planes at scales 3 and 5, i.e. 4 and 6 samples)
CLOSED_FORM = {"cp": 3 * C * R, "triplane": 3 * C * R * R, "vector_matrix": 3 * C * (R * R + R),
               "six_axis": 3 * C * R * R, "multires": 3 * C * (4 * 4 + 6 * 6), "hybrid": 3 * C * R + 3 * C * R * R}


@pytest.fixture(scope="module")
def bench():
    return load_script("nerf_encodings")


def test_parameters_are_the_closed_forms(bench):
    for name, parts in TOY_SPEED.items():
        pair = bench.build_pair(parts, bench.TIMING_BOX, None)
        field = pair["tdfields"]
        assert bench.count(field) == (CLOSED_FORM[name], 4 * CLOSED_FORM[name]), name
        assert field.num_parameters() == CLOSED_FORM[name] and pair["nerfstudio"] is None
        if name != "hybrid":
            assert field.closed_form_parameters() == CLOSED_FORM[name]
    # the hash table: the power of two closest to the tri-planes' count, per level and feature
    args = bench.build_pair(TOY_SPEED["multires"], bench.TIMING_BOX, None)["nerfstudio_args"]["field"]
    assert args["log2_hashmap_size"] == round(math.log2(CLOSED_FORM["multires"] / (2 * C)))


def test_speed_rows_at_toy_sizes(bench):
    for name in ("cp", "hybrid"):  # two pairs, three kinds: each new program costs seconds of numba compilation
        row = bench.measure_speed(name, TOY_SPEED[name], None, points=1024, threads=[1], repeats=2)
        assert tdfields.build(row["tdfields_spec"]).num_parameters() == CLOSED_FORM[name]
        assert row["parameters"] == {"tdfields": CLOSED_FORM[name], "nerfstudio": None}
        assert row["bytes"] == {"tdfields": 4 * CLOSED_FORM[name], "nerfstudio": None}
        timing = row["cpu"]["1"]
        assert timing["tdfields_ms"] > 0 and timing["tdfields_reference_ms"] > 0, timing
        assert "nerfstudio_ms" not in timing and timing["ratio"] is None
        assert [len(v) for v in timing["repeats_ms"].values()] == [2, 2]
        assert row["points"] == 1024 and set(row["sizes"]) == set(TOY_SPEED[name])
        if not torch.cuda.is_available():
            assert row["cuda"].startswith("skipped")


def test_hash_scales_follow_nerfstudio(bench):
    # nerfstudio: floor(min_res * growth ** level), growth = (max / min) ** (1 / (levels - 1)); float rounding
    # makes the top level 63, not 64, at these arguments
    assert bench.HashMatch.scales({"levels": 6, "min_res": 8, "max_res": 64}) == [8, 12, 18, 27, 42, 63]


def test_main_writes_the_json_and_the_figure(bench, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(bench, "TIMING_SIZES", TOY_SPEED)
    monkeypatch.setattr(bench, "PSNR_SIZES", TOY_PSNR)
    monkeypatch.setattr(bench, "nerfstudio", lambda: (None, "nerfstudio missing (test)"))
    argv = ["--pairs", "cp", "hybrid", "--points", "512", "--threads", "1", "--repeats", "1", "--steps", "2",
            "--seconds", "0.2", "--size", "16x20", "--frames", "9", "--rays", "32", "--samples", "8",
            "--out", str(tmp_path)]
    assert bench.main(argv) == 0
    result = json.loads((tmp_path / "nerf_encodings.json").read_text())
    assert (tmp_path / "nerf_encodings.png").stat().st_size > 0
    assert result["nerfstudio"] is None and "missing" in result["nerfstudio_missing"]
    assert {"date", "torch_version", "cpu"} <= set(result["stamp"]) and result["command"].endswith(str(tmp_path))
    assert [r["pair"] for r in result["speed"]] == [r["pair"] for r in result["psnr"]] == ["cp", "hybrid"]
    for row in result["psnr"]:
        assert "nerfstudio" not in row and row["parameters"]["nerfstudio"] is None
        if row["pair"] == "cp":  # density and appearance, both at the toy size
            assert row["parameters"]["tdfields"] == 2 * CLOSED_FORM["cp"]
        runs = row["tdfields"]
        assert runs["at_steps"]["steps"] == 2 and runs["at_seconds"]["steps"] >= 1
        for run in runs.values():
            assert 5 < run["psnr"] < 60 and run["seconds"] > 0 and 0 < run["ssim"] <= 1
            assert run["model_parameters"] > row["parameters"]["tdfields"]  # fields + heads
    assert result["summary"]["ratios"] == {"cp": {"1": None}, "hybrid": {"1": None}}  # no nerfstudio: no ratio
    assert "| cp / TensorCP | 1 |" in capsys.readouterr().out
