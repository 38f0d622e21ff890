"""benchmarks/nerf_end_to_end.py's summary (its runs need the nerfstudio environment of .ci/nerfstudio_job.sh):
medians of time, mean ± std of quality, each variant against the first."""

import pytest

from tests.benchmarks.conftest import script_on_path


def test_each_variant_is_summarised_against_the_first():
    runs = [{"variant": v, "seed": s, "wall_s": w, "step_s": w / 100, "psnr": p, "ssim": 0.9}
            for v, s, w, p in [("ref", 0, 10.0, 25.0), ("ref", 1, 12.0, 25.2), ("new", 0, 5.0, 25.4),
                               ("new", 1, 7.0, 25.6)]]
    with script_on_path("nerf_end_to_end") as bench:
        ref, new = bench.summarise(runs, ["ref", "new", "not run yet"])
    assert ref["wall_ratio"] == 1 and new["wall_s"] == 6.0 and new["wall_ratio"] == pytest.approx(6 / 11)
    assert new["psnr_difference"] == pytest.approx(0.4) and new["psnr_std"] == pytest.approx(0.1414, abs=1e-4)
