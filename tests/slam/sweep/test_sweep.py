"""lrslam sweep: planning and bad input, finished-run detection, summaries (no Ray), and a tiny sweep on a local Ray."""

import json
import logging
import shutil
import statistics
import time
from pathlib import Path

import pytest

from slam.errors import SlamInputError
from slam.sweep import (RunSpec, SerialEngine, cpus_for, execute, failed_record, finished_metrics, plan, summarize,
                        summary_markdown)

# 4 frames, a few iterations: every stage of a run, in a few seconds
SWEEP_TINY = ["profile=quality", "data.max_frames=4", "tracking.iters=2", "tracking.pixels=100", "mapping.iters=2",
              "mapping.iters_first=3", "mapping.pixels=200", "rendering.n_stratified=8", "rendering.n_importance=4"]


# --------------------------------------------------------------------------------------------------- planning
def test_plan_names_and_orders_runs(tiny_seq, tmp_path):
    specs = plan([f"synthetic={tiny_seq}"], ["lrslam", "eslam"], 2, tmp_path / "sw", overrides=["tracking.iters=2"],
                 threads=1)
    assert [(s.representation, s.seed) for s in specs] == [("lrslam", 0), ("lrslam", 1), ("eslam", 0), ("eslam", 1)]
    assert [Path(s.run_dir).name for s in specs] == ["synthetic-lrslam-s0", "synthetic-lrslam-s1",
                                                      "synthetic-eslam-s0", "synthetic-eslam-s1"]
    assert all(Path(s.run_dir).parent == (tmp_path / "sw").resolve() for s in specs)
    assert specs[1].config_overrides() == ["representation=lrslam", "seed=1", "threads=1", "tracking.iters=2",
                                           f"data.path={Path(tiny_seq).resolve()}"]


def test_a_parallel_mode_run_reserves_a_cpu_per_loop_thread(tiny_seq, tmp_path):
    par, seq = (plan([f"synthetic={tiny_seq}"], ["lrslam"], 1, tmp_path / n, overrides=[f"parallel={v}"], threads=1)[0]
                for n, v in (("p", "true"), ("s", "false")))
    assert cpus_for(par, 1) == 2 and cpus_for(seq, 1) == 1 and cpus_for(par, 2) == 4
    assert cpus_for(par, 1, available=1) == 1  # never more than the cluster has: the task would wait forever
    base = plan([f"synthetic={tiny_seq}"], ["lrslam"], 1, tmp_path / "b", threads=1)[0]
    assert cpus_for(base, 1) == 2  # parallel is the base default


def test_plan_slashes_and_same_preset_twice(tiny_seq, tmp_path):
    other = tmp_path / "copy_b"
    shutil.copytree(tiny_seq, other)
    specs = plan([f"synthetic={tiny_seq}", f"synthetic={other}"], ["lrslam"], 1, tmp_path / "sw")
    assert [Path(s.run_dir).name for s in specs] == [f"synthetic@{Path(tiny_seq).name}-lrslam-s0",
                                                      "synthetic@copy_b-lrslam-s0"]
    assert specs[1].label == "synthetic@copy_b"
    tum = plan(["tum/fr1_rpy-cpu=" + str(tiny_seq)], ["lrslam"], 1, tmp_path / "sw", check_data=False)
    assert Path(tum[0].run_dir).name == "tum_fr1_rpy-cpu-lrslam-s0"


def test_plan_yaml_preset_is_made_absolute(tiny_seq, tmp_path, monkeypatch):
    (tmp_path / "mine.yaml").write_text("inherit: synthetic\ntracking: {iters: 3}\n")
    monkeypatch.chdir(tmp_path)
    (spec,) = plan([f"mine.yaml={tiny_seq}"], ["lrslam"], 1, "sw")
    assert spec.preset == str(tmp_path / "mine.yaml") and Path(spec.run_dir) == tmp_path / "sw" / "mine-lrslam-s0"


@pytest.mark.parametrize("configs, reps, seeds, over, match", [
    (["nope"], ["lrslam"], 1, [], "unknown preset 'nope'"),
    (["synthetic"], ["tri"], 1, [], "unknown representation 'tri'"),
    (["synthetic"], ["lrslam"], 0, [], "--seeds must be >= 1"),
    (["synthetic=/no/such/folder"], ["lrslam"], 1, [], "data folder not found: /no/such/folder"),
    (["tum/fr1_rpy-cpu"], ["lrslam"], 1, [], "pass its folder"),
    (["synthetic"], ["lrslam"], 1, ["seed=4"], "override 'seed' is set by the sweep"),
    (["synthetic"], ["lrslam"], 1, ["tracking.nope=1"], "unknown config key 'tracking.nope'"),
    (["synthetic"], ["lrslam", "lrslam"], 1, [], "given twice"),
])
def test_plan_bad_input(configs, reps, seeds, over, match, tmp_path):
    with pytest.raises(SlamInputError, match=match):
        plan(configs, reps, seeds, tmp_path / "sw", overrides=over)


@pytest.mark.parametrize("argv, message", [
    (["--config", "nope", "--representation", "lrslam", "--seeds", "2"], "unknown preset 'nope'"),
    (["--config", "synthetic", "--representation", "lrslam", "--seeds", "0"], "--seeds must be >= 1"),
    (["--config", "synthetic=/no/such", "--representation", "lrslam", "--seeds", "1"], "data folder not found"),
    (["--config", "synthetic", "--representation", "x", "--seeds", "1"], "unknown representation 'x'"),
    (["--config", "synthetic", "tracking.iters=2", "--representation", "lrslam", "--seeds", "1"],
     "looks like a key=value override"),
])
def test_cli_bad_input_exits_2_before_ray(argv, message, tmp_path, capsys, monkeypatch):
    import slam.sweep
    from slam.cli import main

    def no_ray(*a, **k):
        raise AssertionError("Ray must not start on bad input")

    monkeypatch.setattr(slam.sweep.RayEngine, "run", no_ray)
    assert main(["sweep", *argv, "--out", str(tmp_path / "sw")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_cli_without_ray_names_the_install_command(tmp_path, capsys, monkeypatch):
    import sys

    from slam.cli import main

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    assert main(["sweep", "--config", "synthetic", "--representation", "lrslam", "--seeds", "1",
                 "--out", str(tmp_path / "sw")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install "ray>=2.9"' in err and '[sweep]' in err


# --------------------------------------------------------------------------------------------------- records
def test_finished_metrics(tmp_path):
    assert finished_metrics(tmp_path) is None
    (tmp_path / "metrics.json").write_text("{not json")
    assert finished_metrics(tmp_path) is None
    (tmp_path / "metrics.json").write_text(json.dumps({"ate_rmse_m": 0.01, "partial": True}))
    assert finished_metrics(tmp_path) is None
    (tmp_path / "metrics.json").write_text(json.dumps({"ate_rmse_m": 0.01, "partial": False}))
    assert finished_metrics(tmp_path) == {"ate_rmse_m": 0.01, "partial": False}


def _spec(rep="lrslam", seed=0, label="synthetic"):
    return RunSpec("synthetic", None, label, rep, seed, ("tracking.iters=2",), f"/sw/{label}-{rep}-s{seed}")


def _ok(rep, seed, ate, fpt, total, label="synthetic"):
    return {"ate_rmse_m": ate, "fpt_s": fpt, "parameters": {"total": total}, **_spec(rep, seed, label).identity(),
            "status": "ok"}


def test_summary_mean_std_and_failures():
    try:
        raise RuntimeError("mapping exploded\nsecond line")
    except RuntimeError as exc:
        bad = failed_record(_spec("eslam", 2), exc)
    runs = [_ok("lrslam", 0, 0.010, 0.20, 1000), _ok("lrslam", 1, 0.012, 0.30, 1000), _ok("lrslam", 2, 0.017, 0.25, 1000),
            _ok("eslam", 0, 0.020, 0.10, 5000), _ok("eslam", 1, 0.030, 0.14, 5000), bad]
    s = summarize(runs, "ray 9.9")
    assert s["engine"] == "ray 9.9" and s["runs"] == runs
    lr, es = s["groups"]
    assert (lr["representation"], lr["runs"], lr["ok"], lr["failed"]) == ("lrslam", 3, 3, 0)
    assert lr["ate_rmse_m_mean"] == pytest.approx(0.013)
    assert lr["ate_rmse_m_std"] == pytest.approx(statistics.stdev([0.010, 0.012, 0.017]))
    assert lr["fpt_s_mean"] == pytest.approx(0.25) and lr["parameters_std"] == 0
    assert (es["runs"], es["ok"], es["failed"], es["seeds"]) == (3, 2, 1, [0, 1])
    assert es["ate_rmse_m_mean"] == pytest.approx(0.025)
    assert bad["error"] == "RuntimeError: mapping exploded" and "raise RuntimeError" in bad["traceback"]
    md = summary_markdown(s)
    rows = [ln for ln in md.splitlines() if ln.startswith("| synthetic")]
    assert rows[0] == "| synthetic | lrslam | 3 / 3 | 1.300 ± 0.361 | 0.250 ± 0.050 | 1,000 |"
    assert rows[1] == "| synthetic | eslam | 2 / 3 | 2.500 ± 0.707 | 0.120 ± 0.028 | 5,000 |"
    assert "## Failed runs" in md and "synthetic eslam seed 2 (`/sw/synthetic-eslam-s2`): RuntimeError: mapping exploded" in md


def test_summary_single_run_and_no_ate():
    s = summarize([{**_ok("lrslam", 0, None, 0.2, 10)}], "serial")
    g = s["groups"][0]
    assert g["ate_rmse_m_mean"] is None and g["fpt_s_std"] is None
    assert "| synthetic | lrslam | 1 / 1 | - | 0.200 | 10 |" in summary_markdown(s)


# --------------------------------------------------------------------------------------------------- running
def test_serial_sweep_records_a_failing_run_and_reuses_finished_ones(tiny_seq, tmp_path, monkeypatch):
    """Engine-independent: a run that raises is recorded, the others finish; a second pass reruns nothing."""
    import slam.run.runner

    specs = plan([f"synthetic={tiny_seq}"], ["lrslam"], 2, tmp_path / "sw", overrides=SWEEP_TINY, mesh=False)
    real = slam.run.runner.run_to_folder

    def flaky(cfg, out, **kw):
        if cfg.seed == 1:
            raise FloatingPointError("seed 1 diverged")
        return real(cfg, out, **kw)

    monkeypatch.setattr(slam.run.runner, "run_to_folder", flaky)
    s = execute(specs, SerialEngine(), out=tmp_path / "sw", log=lambda m: None)
    ok, bad = s["runs"]
    assert ok["status"] == "ok" and ok["seed"] == 0 and ok["num_frames"] == 4 and ok["ate_rmse_m"] > 0
    assert bad["status"] == "failed" and bad["error"] == "FloatingPointError: seed 1 diverged"
    assert "seed 1 diverged" in (Path(bad["run_dir"]) / "error.txt").read_text()
    on_disk = json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert on_disk["engine"] == "serial" and [r["status"] for r in on_disk["runs"]] == ["ok", "failed"]

    monkeypatch.setattr(slam.run.runner, "run_to_folder", real)
    mtime = (Path(ok["run_dir"]) / "metrics.json").stat().st_mtime_ns
    s2 = execute(specs, SerialEngine(), out=tmp_path / "sw", log=lambda m: None)
    assert [r["status"] for r in s2["runs"]] == ["ok", "ok"]
    assert s2["runs"][0].get("reused") is True and not s2["runs"][1].get("reused")
    assert (Path(ok["run_dir"]) / "metrics.json").stat().st_mtime_ns == mtime
    assert s2["runs"][0]["ate_rmse_m"] == ok["ate_rmse_m"]


def test_interrupted_run_goes_on_from_its_checkpoint(tiny_seq, tmp_path):
    """A run stopped by SIGINT after two frames (partial outputs and a checkpoint) is resumed, not restarted."""
    import os
    import signal

    from slam.config import load_config
    from slam.engine.observers import Observer
    from slam.run.runner import RunInterrupted, run_to_folder
    from slam.sweep import interrupted

    (spec,) = plan([f"synthetic={tiny_seq}"], ["lrslam"], 1, tmp_path / "sw", overrides=SWEEP_TINY, mesh=False)

    class Interrupt(Observer):
        def on_frame(self, run, record):
            if record.k == 1:
                os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(RunInterrupted):
        run_to_folder(load_config(spec.preset, spec.config_overrides()), spec.run_dir, progress=False, mesh=False,
                      observers=[Interrupt()])
    assert interrupted(spec.run_dir) and finished_metrics(spec.run_dir) is None
    logs = []
    (spec2,) = plan([f"synthetic={tiny_seq}"], ["lrslam"], 1, tmp_path / "sw", overrides=SWEEP_TINY, mesh=False,
                    threads=2)  # today's sweep asks for 2 threads; the run was started with 1
    (rec,) = execute([spec2], SerialEngine(), log=logs.append)["runs"]
    assert "1 interrupted runs go on from their checkpoints" in logs
    assert rec["status"] == "ok" and rec["resumed_from"] == 2 and rec["num_frames"] == 4
    assert rec["threads"] == 1  # the run's own config: what it computes does not depend on when it was resumed
    from slam.engine.runtime import float_fingerprint

    assert rec["float_fingerprint"] == float_fingerprint()  # which machine's rounding its seed repeats on
    assert not json.loads((Path(spec.run_dir) / "metrics.json").read_text()).get("partial")


def test_a_stopped_sweep_leaves_its_running_runs_resumable(tiny_seq, tmp_path):
    """Ctrl-C of a sweep touches its stop file: a running run stops after its frame with partial outputs (the
    next sweep resumes it), a run not started yet does not start, and Ray's tasks are not killed before they
    have written them (the fake Ray records the order of events)."""
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, run_to_folder
    from slam.sweep import interrupted, run_one
    from slam.sweep.engines import RayEngine

    specs = plan([f"synthetic={tiny_seq}"], ["lrslam"], 2, tmp_path / "sw", overrides=SWEEP_TINY, mesh=False)
    stop = tmp_path / "sw" / ".stop"

    from slam.engine.observers import Observer

    class TouchAt1(Observer):
        def on_frame(self, run, record):
            if record.k == 1:
                stop.touch()

    with pytest.raises(RunInterrupted):
        run_to_folder(load_config(specs[0].preset, specs[0].config_overrides()), specs[0].run_dir, progress=False,
                      mesh=False, observers=[TouchAt1()], stop_file=stop)
    assert interrupted(specs[0].run_dir)
    import dataclasses

    rec = run_one(dataclasses.replace(specs[1], stop_file=str(stop)))
    assert rec["status"] == "interrupted" and not Path(specs[1].run_dir, "metrics.json").exists()

    events = []

    class FakeRay:
        def wait(self, refs, num_returns, timeout=None):
            events.append(("wait", stop.exists()))
            return list(refs[:1]), []

        def get(self, ref):
            return {"run_dir": ref, "status": "interrupted"}

        def cancel(self, ref, force=False):
            events.append(("cancel", force))

    stop.unlink()
    engine = RayEngine.__new__(RayEngine)
    engine.ray = FakeRay()
    got = []
    engine._stop({"a": specs[0]}, got.append, [dataclasses.replace(s, stop_file=str(stop)) for s in specs])
    assert events == [("wait", True)] and got == [{"run_dir": "a", "status": "interrupted"}]


def test_finished_run_with_another_config_is_not_reused(tiny_seq, tmp_path):
    specs = plan([f"synthetic={tiny_seq}"], ["lrslam"], 1, tmp_path / "sw", overrides=SWEEP_TINY, mesh=False)
    execute(specs, SerialEngine(), out=tmp_path / "sw", log=lambda m: None)
    other = plan([f"synthetic={tiny_seq}"], ["lrslam"], 1, tmp_path / "sw",
                 overrides=[*SWEEP_TINY[:-1], "rendering.n_importance=6"], mesh=False)
    with pytest.raises(SlamInputError, match="rendering.n_importance: 4 there, 6 now"):
        execute(other, SerialEngine(), out=tmp_path / "sw", log=lambda m: None)


@pytest.mark.slow
def test_tiny_sweep_on_local_ray(tiny_seq, tmp_path, capsys):
    """The real thing: `lrslam sweep` on a local Ray, 2 seeds x 2 representations plus a broken copy of the
    data whose runs fail; then the same command again, which reruns only the failed runs."""
    pytest.importorskip("ray")
    import ray

    from slam.cli import main

    broken = tmp_path / "broken"
    shutil.copytree(tiny_seq, broken)
    (broken / "results" / "frame000002.png").write_bytes(b"not a png")  # frame 2 fails to decode
    out = tmp_path / "sw"
    argv = ["sweep", "--config", f"synthetic={tiny_seq}", f"synthetic={broken}", "--representation", "lrslam",
            "eslam", "--seeds", "2", "--out", str(out), "--no-mesh", *SWEEP_TINY]
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
             runtime_env={"env_vars": {"PYTHONPATH": str(Path(__file__).resolve().parents[3])}})
    try:
        t0 = time.perf_counter()
        assert main(argv) == 1  # some runs failed
        first = time.perf_counter() - t0
        s = json.loads((out / "summary.json").read_text())
        assert s["engine"] == f"ray {ray.__version__}"
        good = [r for r in s["runs"] if r["data"] == str(Path(tiny_seq).resolve())]
        bad = [r for r in s["runs"] if r["data"] == str(broken.resolve())]
        assert [(r["representation"], r["seed"], r["status"]) for r in good] == [
            ("lrslam", 0, "ok"), ("lrslam", 1, "ok"), ("eslam", 0, "ok"), ("eslam", 1, "ok")]
        for r in good:
            assert r["num_frames"] == 4 and r["ate_rmse_m"] > 0 and r["fpt_s"] > 0
            assert r["overrides"] == SWEEP_TINY and Path(r["run_dir"], "trajectory.txt").exists()
            assert json.loads(Path(r["run_dir"], "metrics.json").read_text())["seed"] == r["seed"]
        # different seeds are different runs
        assert good[0]["ate_rmse_m"] != good[1]["ate_rmse_m"]
        assert len(bad) == 4 and all(r["status"] == "failed" and r["error"] and r["traceback"] for r in bad)
        assert {r["label"] for r in bad} == {"synthetic@broken"}
        md = (out / "summary.md").read_text()
        lr = [r["ate_rmse_m"] for r in good[:2]]
        row = next(ln for ln in md.splitlines() if ln.startswith(f"| synthetic@{Path(tiny_seq).name} | lrslam |"))
        assert f"| 2 / 2 | {100 * statistics.fmean(lr):.3f} ± {100 * statistics.stdev(lr):.3f} |" in row
        assert "| synthetic@broken | eslam | 0 / 2 | - | - | - |" in md and "## Failed runs" in md

        mtimes = {r["run_dir"]: Path(r["run_dir"], "metrics.json").stat().st_mtime_ns for r in good}
        capsys.readouterr()
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert "4 of 8 runs already finished: reused" in err and "[4/4]" in err and "[5/" not in err
        s2 = json.loads((out / "summary.json").read_text())
        assert [r.get("reused", False) for r in s2["runs"]] == [True] * 4 + [False] * 4
        assert {r["run_dir"]: Path(r["run_dir"], "metrics.json").stat().st_mtime_ns for r in good} == mtimes
        assert [r["ate_rmse_m"] for r in s2["runs"][:4]] == [r["ate_rmse_m"] for r in good]
        print(f"first sweep {first:.1f} s")
    finally:
        ray.shutdown()


def test_a_finished_run_of_an_older_version_is_reused_when_only_keys_added_since_are_missing(tmp_path):
    """A run folder written before a key existed (here ``data.realtime``) computed with that key's default: a sweep
    that plans the same config reuses it instead of calling it another config; a real difference is still named."""
    import yaml

    from slam.config import load_config
    from slam.sweep.runs import _check_same_config

    spec = RunSpec("synthetic", None, "synthetic", "lrslam", 0, ("tracking.iters=2",), str(tmp_path))
    planned = load_config("synthetic", list(spec.config_overrides()), profile="quality").to_dict()
    old = yaml.safe_load(yaml.safe_dump(planned))
    del old["data"]["realtime"]
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(old))
    _check_same_config(spec, planned)
    old["tracking"]["iters"] = 3
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(old))
    with pytest.raises(SlamInputError, match="tracking.iters: 3 there, 2 now"):
        _check_same_config(spec, planned)
