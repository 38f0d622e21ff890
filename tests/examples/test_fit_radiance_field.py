"""examples/fit_radiance_field.py on a tiny synthetic room: it learns (a held-out PSNR an untrained model does not
reach), writes its metrics and renders, matches parameter budgets, and rejects bad input in one line."""

import importlib.util
import json
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "examples" / "fit_radiance_field.py"
# 16 frames of 48x64 (held out: frames 0 and 8), a 100k-parameter CP model, 300 steps of 512 rays x 32 samples:
# about 25 s on one core, numba compilation included
TINY = ["--dataset", "synthetic", "--size", "48x64", "--frames", "16", "--rays", "512", "--samples", "32",
        "--threads", "1", "--kind", "cp", "--budget", "100000"]
# Measured 27.35 dB (seeds 1, 2: 27.53, 27.21; 2026-12-02, AMD EPYC, torch 2.13.0). Below the bound: 1 step
# 17.4 dB, the mean training colour 19.2 dB, and about 22 dB for the fog near the cameras that a model which has not
# found the geometry settles into (as the example did before its initial density was raised).
PSNR_BOUND = 25.3
KEYS = {"psnr", "ssim", "parameters", "seconds", "kind", "steps", "dataset", "image_size", "held_out", "date",
        "torch_version", "tdfields_version", "cpu"}


def _load_script():
    spec = importlib.util.spec_from_file_location("fit_radiance_field", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def script():
    return _load_script()


def test_fits_the_synthetic_room(script, tmp_path):
    assert script.main([*TINY, "--steps", "300", "--out", str(tmp_path / "fit")]) == 0
    metrics = json.loads((tmp_path / "fit" / "metrics.json").read_text())
    assert KEYS <= set(metrics)
    assert metrics["image_size"] == [48, 64] and metrics["held_out"] == 2 and metrics["train_images"] == 14
    assert abs(metrics["parameters"] - 100_000) < 5_000
    assert metrics["psnr"] > PSNR_BOUND, metrics["psnr"]
    assert 0 < metrics["ssim"] <= 1
    renders = sorted(p.name for p in (tmp_path / "fit" / "renders").glob("*.png"))
    assert renders == ["view_000.png", "view_008.png"]

    # the bound can fail: the same model after one step stays far below it
    assert script.main([*TINY, "--steps", "1", "--out", str(tmp_path / "one")]) == 0
    assert json.loads((tmp_path / "one" / "metrics.json").read_text())["psnr"] < PSNR_BOUND - 5


def test_compare_matches_budgets(script, tmp_path, capsys):
    argv = [a for a in TINY if a not in ("--kind", "cp")]
    assert script.main([*argv, "--steps", "1", "--compare", "triplane", "hybrid", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "compare.json").read_text())
    assert [r["kind"] for r in rows] == ["triplane", "hybrid"]
    for row in rows:
        assert abs(row["parameters"] - 100_000) < 10_000, row
        assert (tmp_path / row["kind"] / "metrics.json").is_file()
    assert rows[1]["fields"]["density"]["kind"] == "cp" and rows[1]["fields"]["appearance"]["kind"] == "six_axis"
    assert "| triplane |" in capsys.readouterr().out


@pytest.mark.parametrize("args, message", [
    (["--kind", "tucker"], "unknown kind 'tucker'"),
    (["--steps", "0"], "--steps must be >= 1"),
    (["--data", "/nonexistent/sequence", "--dataset", "tum"], "dataset folder not found"),
])
def test_bad_input_is_one_line(script, args, message, tmp_path, capsys):
    # in this process (a subprocess per case cost 10 s of imports): SystemExit with one line is what Python prints
    # as the whole of stderr, with no traceback
    with pytest.raises(SystemExit) as info:
        script.main([*args, "--out", str(tmp_path)])
    text = info.value.code if isinstance(info.value.code, str) else capsys.readouterr().err
    lines = text.strip().splitlines()
    assert info.value.code != 0 and len(lines) == 1 and message in lines[0], text
