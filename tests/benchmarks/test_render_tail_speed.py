"""benchmarks/render_tail_speed.py: both sides compute the same tail (loss and gradients), the fused side really
runs the fused kernels, and the report holds every round."""

import json

import pytest

from tests.benchmarks.conftest import script_on_path


@pytest.fixture(scope="module")
def bench():
    with script_on_path("render_tail_speed") as module:
        yield module


def test_the_two_sides_agree_and_the_report_holds_every_round(bench, tmp_path, monkeypatch):
    from slam.core import fused_render

    launches, real = [], fused_render._launch
    monkeypatch.setattr(fused_render, "_launch", lambda *a: (launches.append(a[1]), real(*a)))
    batch = bench._inputs(50, 12, "cpu")
    ref = bench.tail_step(batch, False)
    assert launches == []
    fused = bench.tail_step(batch, True)
    assert sorted(launches) == sorted(f"{f}_{d}" for f in ("composite", "color", "loss") for d in ("forward", "backward"))
    for a, b in zip(fused, ref):  # loss, and its gradients to the SDF, the colours and beta
        assert a.shape == b.shape and float(b.abs().max()) > 0
        assert float((a - b).abs().max()) <= 1e-5 * float(b.abs().max())
    assert bench.main(["--smoke", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "render_tail_speed.json").read_text())
    (row,) = report["sizes"]
    assert len(row["seconds"]["reference"]) == len(row["seconds"]["fused"]) == report["repeats"] == 2
    assert max(row["max_abs_diff"].values()) < 1e-5 and row["median_ms"]["fused"] > 0
    assert "| smoke (100 x 12) |" in (tmp_path / "render_tail_speed.md").read_text()


def test_a_device_whose_fused_tail_cannot_run_is_refused(bench, tmp_path, monkeypatch, capsys):
    from tdfields import kernels

    with kernels.use_backend("torch"):  # the reference everywhere: nothing fused to time
        assert bench.main(["--smoke", "--out", str(tmp_path)]) == 2
    assert "cannot run" in capsys.readouterr().err
