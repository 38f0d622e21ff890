"""Side-by-side SLAM comparison: lrslam vs eslam vs CP/CP (and other representations) on the same sequences,
over seeds, as the paper reports it (mean ± std over 5 runs).

Runs ``slam.run.runner.run_to_folder`` for every (sequence, representation, backend, seed) with identical settings and
writes ``slam_compare.json`` (every run's values, per seed), ``slam_compare.csv`` (one row per run) and
``slam_compare.md`` (mean ± std per configuration), stamped with date, library version, CPU and thread count.
Parameter counts come from ``tdfields.report`` via each run's ``metrics.json``.

Usage::

    python benchmarks/slam_compare.py --seeds 5 --out benchmarks/results/seeds      # synthetic + both TUM excerpts
    python benchmarks/slam_compare.py --sequences synthetic --representations lrslam eslam
    python benchmarks/slam_compare.py --sequences tum/fr1_rpy-cpu=../shared/data/tum_fr1_rpy --seeds 5 --jobs 2
    python benchmarks/slam_compare.py --sequences synthetic --backends auto torch --out benchmarks/results/fused

``--seeds N`` runs seeds 0..N-1 (the ``seed`` config key: pixel draws, jitter, window choice, initialisation).
Accuracy is reported as mean ± sample standard deviation over the seeds, with every seed's value in the JSON.

Runs go through :mod:`slam.sweep` (the engine of ``lrslam sweep``): ``--jobs 1`` (the default) runs them one after
another in this process (:class:`slam.sweep.SerialEngine`, with progress bars), ``--jobs J`` runs J at once as
Ray tasks on a local Ray with J CPUs, one torch thread each (a run in parallel mode reserves two CPUs, so
``--jobs 2`` on two cores runs those one at a time: two at once, beside a third run, ran 7.5x slower each), and ``--address`` sends them to a Ray cluster
(:class:`slam.sweep.RayEngine`). Accuracy is exactly the same as run one by one (a run is deterministic for its
seed), but frame times then share the CPU, so timing tables use ``--jobs 1``. Every run is run afresh (no
reuse of earlier run folders: a benchmark measures the code as it is).

``--backends`` repeats every run with each tdfields kernel backend (``auto``: the fused kernels; ``torch``: the
pure-PyTorch reference), for a before/after table of the fused kernels on the same sequence and settings.

``--repeats N`` runs every configuration N times, interleaved (A, B, A, B, ...) so slow phases of a shared machine
hit every configuration alike; ``fpt_s`` is then the median over repeats and seeds. Meshing and mesh metrics run on
the first repeat only (the runs are deterministic for a seed; only their timing varies).
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SHARED = ROOT.parent / "shared" / "data"
DEFAULT_SEQUENCES = ["synthetic", f"tum/fr1_rpy-cpu={SHARED / 'tum_fr1_rpy'}",
                     f"tum/fr1_rpy-cpu={SHARED / 'tum_fr1_rpy_0_124'}"]
RUN_COLUMNS = ["sequence", "data", "representation", "backend", "seed", "repeat", "num_frames", "ate_rmse_cm",
               "ate_mean_cm", "accuracy_cm", "completion_cm", "completion_ratio_pct", "depth_l1_cm", "fpt_s",
               "events", "geometry", "appearance", "decoders", "total"]
METRICS = ["ate_rmse_cm", "ate_mean_cm", "accuracy_cm", "completion_cm", "completion_ratio_pct", "depth_l1_cm",
           "fpt_s"]


def _cm(v):
    return None if v is None else round(100 * v, 4)


def row_of(seq: str, data: str, rep: str, m: dict, backend: str, seed: int, repeat: int) -> dict:
    rec = m.get("reconstruction") or {}
    p = m["parameters"]
    return {
        "sequence": seq, "data": data, "representation": rep, "backend": backend, "seed": seed, "repeat": repeat,
        "num_frames": m["num_frames"], "ate_rmse_cm": _cm(m.get("ate_rmse_m")), "ate_mean_cm": _cm(m.get("ate_mean_m")),
        "accuracy_cm": _cm(rec.get("accuracy_m")), "completion_cm": _cm(rec.get("completion_m")),
        "completion_ratio_pct": None if rec.get("completion_ratio") is None else round(100 * rec["completion_ratio"], 3),
        "depth_l1_cm": _cm(rec.get("depth_l1_m")), "fpt_s": round(m["fpt_s"], 4), "events": len(m.get("events", [])),
        "geometry": p["geometry"], "appearance": p["appearance"], "decoders": p["decoders"], "total": p["total"],
    }


def row_of_record(rec: dict, spec, data: str, repeat: int) -> dict:
    """A finished sweep record (``slam.sweep.run_one``) as a row of this benchmark (``data`` as given)."""
    return row_of(spec.preset, data, spec.representation, rec, spec.backend, spec.seed, repeat)


def summarize(rows: list[dict]) -> list[dict]:
    """One record per (sequence, data, representation, backend): mean, sample std and per-seed values of each
    metric (accuracy over the seeds of the first repeat; frame time as the median over every run)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["sequence"], r["data"], r["representation"], r["backend"]), []).append(r)
    out = []
    for (seq, data, rep, backend), rs in groups.items():
        first = sorted((r for r in rs if r["repeat"] == 0), key=lambda r: r["seed"])
        rec = {"sequence": seq, "data": data, "representation": rep, "backend": backend, "runs": len(rs),
               "seeds": [r["seed"] for r in first], "num_frames": first[0]["num_frames"] if first else None,
               "parameters": {k: first[0][k] for k in ("geometry", "appearance", "decoders", "total")} if first else {},
               "events": [r["events"] for r in first]}
        for key in METRICS:
            vals = [r[key] for r in (rs if key == "fpt_s" else first) if r[key] is not None]
            rec[key] = {"values": vals, "mean": statistics.fmean(vals) if vals else None,
                        "std": statistics.stdev(vals) if len(vals) > 1 else (0.0 if vals else None),
                        "median": statistics.median(vals) if vals else None}
        out.append(rec)
    return out


def _pm(stat: dict, digits: int = 2) -> str:
    if stat["mean"] is None:
        return "-"
    if len(stat["values"]) == 1:
        return f"{stat['mean']:.{digits}f}"
    return f"{stat['mean']:.{digits}f} ± {stat['std']:.{digits}f}"


def markdown(summary: list[dict], stamp: dict, command: str) -> str:
    lines = [f"Measured {stamp['date']} with tdfields {stamp['version']}, torch {stamp['torch']}, on {stamp['cpu']}, "
             f"1 thread per run. `{command}`", "",
             "| sequence | representation | backend | seeds | ATE RMSE cm (mean ± std) | ATE RMSE per seed | "
             "FPT s (median) | accuracy cm | completion ratio % | parameters |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        seq = s["sequence"] + (f" ({Path(s['data']).name})" if s["data"] else "")
        per_seed = " / ".join(f"{v:.2f}" for v in s["ate_rmse_cm"]["values"])
        fpt = "-" if s["fpt_s"]["median"] is None else f"{s['fpt_s']['median']:.3f}"
        lines.append(f"| {seq} | {s['representation']} | {s['backend']} | {len(s['seeds'])} | {_pm(s['ate_rmse_cm'])} "
                     f"| {per_seed} | {fpt} | {_pm(s['accuracy_cm'])} | {_pm(s['completion_ratio_pct'], 1)} "
                     f"| {s['parameters'].get('total', 0):,} |")
    return "\n".join(lines) + "\n"


def _fail(msg: str) -> int:
    print(f"slam_compare: error: {msg}", file=sys.stderr)
    return 2


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", nargs="+", default=DEFAULT_SEQUENCES,
                    help="PRESET or PRESET=DATA_PATH (default: synthetic and both TUM fr1_rpy excerpts, CPU preset)")
    ap.add_argument("--representations", nargs="+", default=["lrslam", "eslam", "cp_cp"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--no-mesh", action="store_true", help="skip meshing and mesh metrics")
    ap.add_argument("--backends", nargs="+", default=["auto"], choices=["auto", "torch", "numba"],
                    help="tdfields kernel backends to run each configuration with (default: auto)")
    ap.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1 per configuration (default 1)")
    ap.add_argument("--repeats", type=int, default=1,
                    help="runs per configuration and seed, interleaved; FPT is their median (default 1)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="runs at once, as Ray tasks (default 1: one after another in this process; "
                         ">1 only for accuracy, not timing)")
    ap.add_argument("--address", default=None, metavar="RAY_ADDRESS",
                    help="run on this Ray cluster instead (ray.init(address=...))")
    ap.add_argument("--quiet", action="store_true", help="no per-run progress bars")
    ap.add_argument("overrides", nargs="*", metavar="key=value", help="applied to every run")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        return _fail(f"--seeds must be >= 1, got {args.seeds}")
    if args.repeats < 1:
        return _fail(f"--repeats must be >= 1, got {args.repeats}")
    if args.jobs < 1:
        return _fail(f"--jobs must be >= 1, got {args.jobs}")

    import torch

    import tdfields
    from slam.config import REPRESENTATIONS, load_config
    from slam.errors import SlamInputError
    from slam.engine.runtime import cpu_name, float_fingerprint

    bad = [r for r in args.representations if r not in REPRESENTATIONS]
    if bad:
        return _fail(f"unknown representation '{bad[0]}'; choose from {', '.join(REPRESENTATIONS)}")
    from slam.sweep import RayEngine, RunSpec, SerialEngine, execute, require_ray

    out = Path(args.out)
    specs, given = [], {}  # run folder -> (data as given, repeat)
    for seq in args.sequences:
        preset, _, data = seq.partition("=")
        if data and not Path(data).exists():
            return _fail(f"{preset}: data folder not found: {data}")
        for repeat in range(args.repeats):
            for seed in range(args.seeds):
                for backend in args.backends:
                    for rep in args.representations:
                        spec_data = str(Path(data).resolve()) if data else None
                        name = preset.replace("/", "_") + (f"-{Path(data).name}" if data else "")
                        suffix = ("" if backend == "auto" else f"-{backend}") + f"-s{seed}" + (
                            f"-r{repeat}" if repeat else "")
                        spec = RunSpec(preset=preset, data=spec_data, label=name, representation=rep, seed=seed,
                                       overrides=tuple(args.overrides), run_dir=str(out / "runs" / f"{name}-{rep}{suffix}"),
                                       mesh=not args.no_mesh and repeat == 0, threads=1, backend=backend,
                                       tag=f"repeat {repeat}", progress=not args.quiet and args.jobs == 1 and not args.address)
                        try:
                            load_config(preset, spec.config_overrides())  # every preset, key and value checked first
                        except SlamInputError as exc:
                            return _fail(str(exc))
                        specs.append(spec)
                        given[spec.run_dir] = (data, repeat)
    out.mkdir(parents=True, exist_ok=True)
    try:
        if args.jobs == 1 and args.address is None:
            engine = SerialEngine()
        else:
            require_ray()
            engine = RayEngine(address=args.address, cpus_per_run=1, num_cpus=args.jobs)
        summary_runs = execute(specs, engine, reuse=False)["runs"]
    except SlamInputError as exc:
        return _fail(str(exc))
    by_dir = {s.run_dir: s for s in specs}
    rows = [row_of_record(r, by_dir[r["run_dir"]], *given[r["run_dir"]]) for r in summary_runs if r["status"] == "ok"]
    failed = [{"label": f"{r['label']} {r['representation']} [{r['backend']}] seed {r['seed']} {r['tag']}",
               "error": r["error"], "traceback": r.get("traceback")} for r in summary_runs if r["status"] != "ok"]
    for f in failed:
        print(f"FAILED {f['label']}: {f['error']}", file=sys.stderr)
    stamp = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "version": tdfields.__version__,
             "cpu": cpu_name(), "threads": 1, "torch": torch.__version__, "jobs": args.jobs,
             "engine": getattr(engine, "name", "serial"), "float_fingerprint": float_fingerprint()}
    command = "python benchmarks/slam_compare.py " + " ".join(argv if argv is not None else sys.argv[1:])
    summary = summarize(rows)
    (out / "slam_compare.json").write_text(json.dumps(
        {"stamp": stamp, "command": command, "summary": summary, "runs": rows, "failed": failed}, indent=2))
    with open(out / "slam_compare.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=RUN_COLUMNS)
        w.writeheader()
        w.writerows(rows)
    md = markdown(summary, stamp, command)
    (out / "slam_compare.md").write_text(md)
    print(md)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
