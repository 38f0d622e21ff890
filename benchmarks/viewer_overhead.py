"""What logging a run to Rerun costs: the same ``lrslam run`` with and without ``--rerun``, interleaved.

Each run is its own process (``python -m slam.cli run ... --no-mesh [--rerun FILE]``), alternating plain /
logged in ABBA order (plain, logged, logged, plain, ...) so slow phases of a shared machine hit both alike. Per run it reads ``metrics.json``: ``fpt_s`` (mean
tracking + mapping time per frame, which excludes the observers) and ``loop_s`` (the whole loop, observers
included: the number that shows the logging), the process's CPU seconds (all threads, so Rerun's
background encoding and writing count; less sensitive to other load on the machine than wall time) and, for
logged runs, the seconds the observer itself spent logging. Writes ``viewer_overhead.json`` and ``.md`` to ``--out``.

Usage::

    python benchmarks/viewer_overhead.py --repeats 3                  # TUM excerpt, tum/fr1_rpy-cpu
    python benchmarks/viewer_overhead.py --repeats 4 --pairs 3                  # plus 3 simultaneous pairs
    python benchmarks/viewer_overhead.py --repeats 3 --rerun-args --rerun-jpeg 80
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def one_run(config: str, data: str | None, out: Path, rerun: Path | None, extra: list[str],
            overrides: list[str]) -> dict:
    cmd = [sys.executable, "-m", "slam.cli", "run", "--config", config, "--out", str(out), "--no-mesh", "--quiet"]
    if data:
        cmd += ["--data", data]
    if rerun is not None:
        cmd += ["--rerun", str(rerun), *extra]
    cmd += overrides
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return _result(out, rerun, proc.stdout, wall, (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime))


def pair_run(config: str, data: str | None, out: Path, extra: list[str], overrides: list[str]) -> list[dict]:
    """A plain and a logged run at the same time: both see the same load from the rest of the machine."""
    procs = []
    for logged in (False, True):
        run_dir = out / ("rerun" if logged else "plain")
        rrd = run_dir / "run.rrd" if logged else None
        cmd = [sys.executable, "-m", "slam.cli", "run", "--config", config, "--out", str(run_dir), "--no-mesh",
               "--quiet"] + (["--data", data] if data else []) + (["--rerun", str(rrd), *extra] if logged else [])
        procs.append((run_dir, rrd, time.perf_counter(), subprocess.Popen(cmd + overrides, cwd=ROOT,
                                                                         stdout=subprocess.PIPE, text=True)))
    res = []
    for run_dir, rrd, t0, p in procs:
        # per-process CPU from wait4: RUSAGE_CHILDREN would mix the two
        _, status, usage = os.wait4(p.pid, 0)
        if os.waitstatus_to_exitcode(status) != 0:
            raise RuntimeError(f"run into {run_dir} failed")
        res.append(_result(run_dir, rrd, p.stdout.read(), time.perf_counter() - t0, usage.ru_utime + usage.ru_stime))
    return res


def _result(out: Path, rerun: Path | None, stdout: str, wall: float, cpu: float) -> dict:
    m = json.loads((out / "metrics.json").read_text())
    n = m["num_frames"]
    found = re.search(r"logging took ([0-9.]+) s", stdout)
    return {"rerun": rerun is not None, "fpt_s": m["fpt_s"], "loop_s": m["loop_s"], "loop_per_frame_s": m["loop_s"] / n,
            "num_frames": n, "process_wall_s": wall, "process_cpu_s": cpu,
            "log_s": float(found.group(1)) if found else None,
            "rrd_bytes": rerun.stat().st_size if rerun is not None else None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="tum/fr1_rpy-cpu")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "tum_fr1_rpy"))
    ap.add_argument("--repeats", type=int, default=3, help="runs of each kind (default 3)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "viewer_overhead"))
    ap.add_argument("--rerun-args", nargs=argparse.REMAINDER, default=[],
                    help="extra lrslam run flags for the logged runs (e.g. --rerun-jpeg 80)")
    ap.add_argument("--overrides", nargs="*", default=[], metavar="key=value")
    ap.add_argument("--pairs", type=int, default=0,
                    help="also run N plain/logged pairs at the same time (paired under the same load)")
    args = ap.parse_args(argv)
    from slam.engine.runtime import cpu_name
    import tdfields

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = []
    for r in range(args.repeats):
        # ABBA order: a machine getting busier or quieter over the runs favours neither kind
        for logged in ((False, True) if r % 2 == 0 else (True, False)):
            run_dir = out / "runs" / f"{'rerun' if logged else 'plain'}-{r}"
            rrd = run_dir / "run.rrd" if logged else None
            res = one_run(args.config, args.data, run_dir, rrd, args.rerun_args, args.overrides)
            res["repeat"] = r
            runs.append(res)
            print(f"run {r + 1}/{args.repeats} {'rerun' if logged else 'plain'}: FPT {res['fpt_s']:.3f} s, "
                  f"loop {res['loop_per_frame_s']:.3f} s/frame, CPU {res['process_cpu_s']:.1f} s, "
                  f"logging {res['log_s']} s", file=sys.stderr)
    pairs = []
    for r in range(args.pairs):
        plain, logged = pair_run(args.config, args.data, out / "runs" / f"pair-{r}", args.rerun_args, args.overrides)
        pairs.append({"pair": r, "plain": plain, "rerun": logged,
                      "fpt_ratio": logged["fpt_s"] / plain["fpt_s"],
                      "loop_ratio": logged["loop_per_frame_s"] / plain["loop_per_frame_s"]})
        print(f"pair {r + 1}/{args.pairs}: loop {plain['loop_per_frame_s']:.3f} (plain) vs "
              f"{logged['loop_per_frame_s']:.3f} s/frame (rerun)", file=sys.stderr)
    med = {}
    for logged in (False, True):
        sel = [x for x in runs if x["rerun"] == logged]
        med["rerun" if logged else "plain"] = {k: statistics.median(x[k] for x in sel)
                                              for k in ("fpt_s", "loop_per_frame_s", "process_cpu_s")}
    overhead = {k: med["rerun"][k] / med["plain"][k] - 1 for k in ("fpt_s", "loop_per_frame_s", "process_cpu_s")}
    stamp = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "version": tdfields.__version__,
             "cpu": cpu_name(), "omp_num_threads": os.environ.get("OMP_NUM_THREADS")}
    res = {"stamp": stamp, "config": args.config, "data": args.data, "rerun_args": args.rerun_args,
           "overrides": args.overrides, "runs": runs, "median": med, "overhead": overhead, "pairs": pairs}
    (out / "viewer_overhead.json").write_text(json.dumps(res, indent=2))
    lines = [f"# Rerun logging overhead ({stamp['date']}, tdfields {stamp['version']}, {stamp['cpu']})", "",
             f"`{args.config}`, {runs[0]['num_frames']} frames, `--no-mesh`; logged runs add "
             f"`--rerun FILE {' '.join(args.rerun_args)}`".rstrip() + ".", "",
             "| run | kind | FPT (s) | loop per frame (s) | process CPU (s) | logging (s) | recording |",
             "|---|---|---|---|---|---|---|"]
    for x in runs:
        size = "-" if x["rrd_bytes"] is None else f"{x['rrd_bytes'] / 1e6:.1f} MB"
        log_s = "-" if x["log_s"] is None else f"{x['log_s']:.2f}"
        lines.append(f"| {x['repeat'] + 1} | {'rerun' if x['rerun'] else 'plain'} | {x['fpt_s']:.3f} | "
                     f"{x['loop_per_frame_s']:.3f} | {x['process_cpu_s']:.1f} | {log_s} | {size} |")
    lines += ["", f"Medians: FPT {med['plain']['fpt_s']:.3f} -> {med['rerun']['fpt_s']:.3f} s "
                  f"({100 * overhead['fpt_s']:+.1f} %), loop per frame {med['plain']['loop_per_frame_s']:.3f} -> "
                  f"{med['rerun']['loop_per_frame_s']:.3f} s ({100 * overhead['loop_per_frame_s']:+.1f} %), "
                  f"process CPU {med['plain']['process_cpu_s']:.1f} -> {med['rerun']['process_cpu_s']:.1f} s "
                  f"({100 * overhead['process_cpu_s']:+.1f} %)."]
    if pairs:
        lines += ["", "Pairs run at the same time (each pair shares the machine's load):", "",
                  "| pair | loop per frame plain (s) | loop per frame rerun (s) | ratio | logging (s) |", "|---|---|---|---|---|"]
        for p in pairs:
            lines.append(f"| {p['pair'] + 1} | {p['plain']['loop_per_frame_s']:.3f} | {p['rerun']['loop_per_frame_s']:.3f} "
                         f"| {p['loop_ratio']:.3f} | {p['rerun']['log_s']:.2f} |")
        lines += ["", f"Median ratio {statistics.median(p['loop_ratio'] for p in pairs):.3f}."]
    (out / "viewer_overhead.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
