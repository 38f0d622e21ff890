"""slam.sweep.compare and ``lrslam compare``: differences over seeds with their 95 % intervals."""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

import pytest
from scipy import stats

from slam.cli import main
from slam.errors import SlamInputError
from slam.sweep.compare import compare, compare_values, load_runs, seeds_needed

RESULTS = Path(__file__).resolve().parents[3] / "benchmarks" / "results"
#: published screens kept as fixtures (their runs' slam_compare.json, as written then): the 3-seed screens M and O,
#: their 5-seed rerun Q (benchmarks/results/accuracy/ at commit f5975fa) and e413641's lrslam runs (accuracy_lift)
PUBLISHED = Path(__file__).resolve().parent / "published"


def _slam_compare(path: Path, rep_values: dict[str, dict[int, float]], data="/d/tum_fr1_rpy") -> Path:
    runs = [{"sequence": "tum/fr1_rpy-cpu", "data": data, "representation": rep, "backend": "auto", "seed": s,
             "repeat": 0, "ate_rmse_cm": v} for rep, vals in rep_values.items() for s, v in vals.items()]
    path.mkdir(parents=True, exist_ok=True)
    (path / "slam_compare.json").write_text(json.dumps({"runs": runs, "summary": []}))
    return path


def test_paired_difference_is_the_mean_of_per_seed_differences_with_a_student_t_interval():
    a = {0: 2.0, 1: 2.4, 2: 2.1, 3: 2.3}
    b = {0: 2.1, 1: 2.6, 2: 2.2, 3: 2.6}
    method, diff, hw, sd = compare_values(a, b)
    d = [0.1, 0.2, 0.1, 0.3]
    assert method == "paired"
    assert diff == pytest.approx(0.175)
    assert sd == pytest.approx(statistics.stdev(d))
    assert hw == pytest.approx(3.182446 * statistics.stdev(d) / 2.0, rel=1e-5)  # t(0.975, 3) = 3.1824


def test_welch_interval_matches_scipy_when_the_seeds_differ():
    a = {0: 2.0, 1: 2.4, 2: 2.1}
    b = {0: 2.9, 1: 2.5, 2: 3.1, 3: 2.7, 4: 2.8}
    method, diff, hw, _ = compare_values(a, b)
    assert method == "welch"
    res = stats.ttest_ind(list(b.values()), list(a.values()), equal_var=False)
    lo, hi = res.confidence_interval(0.95)
    assert diff == pytest.approx((lo + hi) / 2)
    assert hw == pytest.approx((hi - lo) / 2)


def test_identical_runs_give_exactly_zero_and_a_resolved_constant_shift(tmp_path):
    same = {"eslam": {0: 2.26, 1: 2.11, 2: 2.29}}
    shift = {"eslam": {0: 2.36, 1: 2.21, 2: 2.39}}
    a = _slam_compare(tmp_path / "a", same)
    (d0,) = compare(a, _slam_compare(tmp_path / "b", same))
    assert d0.diff == 0.0 and d0.half_width == 0.0 and d0.verdict == "identical" and d0.seeds_needed is None
    (d1,) = compare(a, _slam_compare(tmp_path / "c", shift))
    assert d1.diff == pytest.approx(0.1) and d1.half_width == pytest.approx(0.0, abs=1e-12)
    assert d1.verdict == "B higher"


def test_seeds_needed_is_the_first_n_whose_interval_excludes_zero():
    n = seeds_needed(0.1, 0.2, paired=True)
    assert stats.t.ppf(0.975, n - 1) * 0.2 / math.sqrt(n) < 0.1
    assert stats.t.ppf(0.975, n - 2) * 0.2 / math.sqrt(n - 1) >= 0.1
    assert seeds_needed(0.001, 0.3, paired=True) is None  # beyond 100
    assert seeds_needed(0.1, 0.2, paired=False) > n  # unpaired: both sides' spread


def test_the_published_3_seed_screen_and_its_5_seed_run_disagree_and_neither_is_resolved():
    # the case that motivated the tool: O (3 seeds) looked better than M on the fast window, Q (5 seeds) worse
    m = PUBLISHED / "M_lr_scaling_lift"
    o = PUBLISHED / "O_track24_map9"
    q = PUBLISHED / "Q_track24_map9_5seeds"
    fast = "tum/fr1_rpy-cpu (tum_fr1_rpy_0_124)"
    (mo,) = [d for d in compare(m, o) if d.config == fast and d.representation == "lrslam"]
    assert mo.method == "paired" and mo.diff < 0 and mo.verdict == "unresolved"
    lift = PUBLISHED / "accuracy_lift"
    (lq,) = [d for d in compare(lift, q) if d.config == fast and d.representation == "lrslam"]
    assert lq.diff > 0 and lq.verdict == "unresolved" and len(lq.a) == len(lq.b) == 5
    assert lq.diff == pytest.approx(statistics.fmean(lq.b) - statistics.fmean(lq.a))


def test_reads_a_sweep_summary_in_metres_and_skips_failed_runs(tmp_path):
    runs = [{"label": "synthetic", "preset": "synthetic", "representation": "lrslam", "seed": 0, "status": "ok",
             "ate_rmse_m": 0.0045},
            {"label": "synthetic", "preset": "synthetic", "representation": "lrslam", "seed": 1, "status": "failed",
             "error": "boom"}]
    (tmp_path / "summary.json").write_text(json.dumps({"engine": "serial", "runs": runs, "groups": []}))
    assert load_runs(tmp_path) == {("synthetic", "lrslam", "auto"): {0: pytest.approx(0.45)}}


@pytest.mark.parametrize("content, match", [
    (None, "no such file"),
    ("{not json", "not a readable JSON"),
    ('{"summary": []}', "no 'runs' list"),
    ('{"runs": [{"seed": 0}]}', "run 0 has no representation"),
    ('{"runs": []}', "no finished run"),
])
def test_bad_result_files_name_the_file(tmp_path, content, match):
    path = tmp_path / "slam_compare.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(SlamInputError, match=match) as err:
        load_runs(path)
    assert str(path) in str(err.value)


def test_cli_prints_the_table_writes_json_and_exits_2_on_bad_input(tmp_path, capsys):
    a = _slam_compare(tmp_path / "a", {"lrslam": {0: 2.0, 1: 2.2, 2: 2.1}})
    b = _slam_compare(tmp_path / "b", {"lrslam": {0: 2.3, 1: 2.5, 2: 2.4}})
    out = tmp_path / "d.json"
    assert main(["compare", str(a), str(b), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    row = ("| tum/fr1_rpy-cpu (tum_fr1_rpy) | lrslam | 3 / 3 | 2.10 | 2.40 | +0.30 ± 0.00 | paired, B lower on 0 of 3 "
           "| B higher |")
    assert row in text
    rows = json.loads(out.read_text())["differences"]
    assert rows[0]["diff"] == pytest.approx(0.3) and rows[0]["a"] == [2.0, 2.2, 2.1]
    other = _slam_compare(tmp_path / "c", {"eslam": {0: 2.0}})
    assert main(["compare", str(a), str(other)]) == 2
    assert "no configuration in common" in capsys.readouterr().err
    assert main(["compare", str(a), str(tmp_path / "missing")]) == 2
    assert "no such file or folder" in capsys.readouterr().err


def test_representations_compares_the_candidate_against_the_reference_on_the_same_configurations(tmp_path, capsys):
    a = _slam_compare(tmp_path / "a", {"eslam": {0: 2.2, 1: 2.4, 2: 2.3}, "lrslam": {0: 2.0, 1: 2.3, 2: 2.1}})
    (d,) = compare(a, representations=("eslam", "lrslam"))
    assert d.representation == "lrslam - eslam" and d.method == "paired"
    assert d.diff == pytest.approx(statistics.fmean([-0.2, -0.1, -0.2]))
    assert main(["compare", str(a), "--representations", "eslam", "lrslam"]) == 0
    assert "| lrslam - eslam | 3 / 3 | 2.30 | 2.13 | -0.17 ± 0.14 | paired, B lower on 3 of 3 | B lower |" in \
        capsys.readouterr().out
    assert main(["compare", str(a), "--representations", "eslam", "cp_cp"]) == 2
    assert "for cp_cp against eslam" in capsys.readouterr().err
    assert main(["compare", str(a)]) == 2
    assert "give B, or --representations" in capsys.readouterr().err


def test_issue_9_fast_window_gap_between_lrslam_and_eslam_is_inside_the_seeds_spread():
    # the published e413641 lrslam runs against eslam's (valid for e413641: tri-planes have step scale 1.0)
    fast = "tum/fr1_rpy-cpu (tum_fr1_rpy_0_124)"
    diffs = {d.config: d for d in compare(RESULTS / "accuracy_final", PUBLISHED / "accuracy_lift", ("eslam", "lrslam"))}
    assert diffs[fast].verdict == "unresolved" and 0 < diffs[fast].diff < diffs[fast].half_width
    before = {d.config: d for d in compare(RESULTS / "accuracy_final", representations=("eslam", "lrslam"))}
    assert before[fast].verdict == "B higher"  # e2051a7: lrslam 0.6 cm behind, resolved


def _stamped(path: Path, fingerprint: str | None) -> Path:
    data = json.loads((path / "slam_compare.json").read_text())
    data["stamp"] = {"float_fingerprint": fingerprint} if fingerprint else {}
    (path / "slam_compare.json").write_text(json.dumps(data))
    return path


def test_runs_from_machines_that_round_differently_are_not_paired(tmp_path, capsys):
    a_vals = {"lrslam": {0: 2.0, 1: 2.4, 2: 2.1, 3: 2.3}}
    b_vals = {"lrslam": {0: 2.1, 1: 2.6, 2: 2.2, 3: 2.6}}
    a = _stamped(_slam_compare(tmp_path / "a", a_vals), "aaaa")
    same = _stamped(_slam_compare(tmp_path / "same", b_vals), "aaaa")
    other = _stamped(_slam_compare(tmp_path / "other", b_vals), "bbbb")
    (d,) = compare(a, same)
    assert d.method == "paired"
    (d,) = compare(a, other)  # the same seeds, but seed s is not the same run on both machines
    assert d.method == "welch, two machines"
    assert (d.diff, d.half_width) == pytest.approx(compare_values(a_vals["lrslam"], b_vals["lrslam"], pair=False)[1:3])
    assert main(["compare", str(a), str(other)]) == 0
    assert "machines that round differently (float fingerprints aaaa / bbbb)" in capsys.readouterr().out
    unstamped = _stamped(_slam_compare(tmp_path / "none", b_vals), None)
    (d,) = compare(a, unstamped)  # nothing recorded: paired as before, and said so
    assert d.method == "paired"
    assert main(["compare", str(a), str(unstamped)]) == 0
    assert "records no float fingerprint" in capsys.readouterr().out


def test_the_fingerprint_is_stable_in_a_process():
    from slam.engine.runtime import float_fingerprint

    f = float_fingerprint()
    assert len(f) == 16 and int(f, 16) >= 0
    float_fingerprint.cache_clear()
    assert float_fingerprint() == f  # recomputed: the same digits


def test_the_fingerprint_tells_apart_torchs_kernels_for_another_instruction_set():
    """ATen's kernels for another instruction set round differently (a run's trajectory changed with
    ATEN_CPU_CAPABILITY=avx2 on an AVX512 machine) though the fingerprint's products did not: the fingerprint must
    change with them. On an AVX512 machine the other set is AVX2 (same products); elsewhere the portable kernels."""
    import os
    import subprocess
    import sys

    import torch

    from slam.engine.runtime import float_fingerprint

    other = "avx2" if torch.backends.cpu.get_cpu_capability() == "AVX512" else "default"
    code = ("import torch; from slam.engine.runtime import float_fingerprint; "
            "print(torch.backends.cpu.get_cpu_capability(), float_fingerprint())")
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, ATEN_CPU_CAPABILITY=other),
                         capture_output=True, text=True, check=True).stdout.split()
    assert out[0] != torch.backends.cpu.get_cpu_capability() and out[1] != float_fingerprint()


def test_a_file_compared_with_itself_needs_no_machine_note(tmp_path, capsys):
    a = _slam_compare(tmp_path / "a", {"eslam": {0: 2.2, 1: 2.3}, "lrslam": {0: 2.1, 1: 2.4}})
    assert main(["compare", str(a), "--representations", "eslam", "lrslam"]) == 0
    assert "fingerprint" not in capsys.readouterr().out  # one file: one machine by construction
