"""Where a frame's time goes (issue 21): tracking, the ICP start, mapping and the tracker's wait for the mapper,
for any checkout, interleaved.

Each variant is a checkout plus ``lrslam run`` arguments (as in ``benchmarks/before_after.py``). Every repeat runs
every variant once, in turn, each in a fresh process with one torch thread. Inside the child, the three functions
every checkout since 29d2223 has under the same names -- ``icp_relative_pose`` (depth ICP: the start, and
relocalisation), ``track_frame`` (the tracker, recovery attempts included) and ``map_frame`` (one mapping call,
in the mapper's thread in parallel mode) -- are wrapped with timers wherever a module holds them, and the run's
``metrics.json`` gives the loop time and ``mapping_wait_s``. Per frame: ``icp_s``, ``tracking_s`` (the tracker
alone, the ICP start not included), ``mapping_s`` (the mapping calls' time divided by the frames; in parallel mode
it overlaps tracking), ``wait_s`` and ``loop_s``; medians over repeats. ``per_call_s`` averages every call,
the first included (the first mapping call is the warm-up's ``iters_first`` iterations, and with
``preload_kernels: false`` it loads the kernels: 3.9 s at ``tum/fr1_rpy-cpu-fast``, against 0.28 s for the rest);
``median_call_after_first_s`` is the steady state. With ``mapper_process: true`` the calls run in the child, where
nothing is wrapped: the per-call columns are empty, and ``mapping_s`` comes from the run's ``metrics.json`` (the
child times its calls). The tracker's and ICP's columns include the preload's rehearsal call (``preload_kernels``),
which the frame time does not. ``minor_faults_per_frame`` counts the
process's minor page faults (its mapper process's included), start-up and all, over the frames, and
``minor_faults_per_call`` those of the calling thread inside each timed function (not counted for a mapper
process): each is a fresh page the C allocator handed out, the cost ``slam.engine.runtime.keep_freed_memory``
exists to avoid.

    git worktree add /tmp/before 29d2223
    python benchmarks/frame_breakdown.py --out benchmarks/results/frame_breakdown --repeats 2 \\
        --variant "29d2223=/tmp/before:--config tum/fr1_rpy-cpu --data ../shared/data/tum_fr1_rpy_0_124" \\
        --variant "now=.:--config tum/fr1_rpy-cpu --data ../shared/data/tum_fr1_rpy_0_124"

Writes ``frame_breakdown.json`` (every run) and ``frame_breakdown.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from before_after import parse_variant, save_variant_runs  # noqa: E402

TIMED = ("icp_relative_pose", "track_frame", "map_frame")

CHILD = r"""
import json, sys, threading, time
sys.path.insert(0, {checkout!r})
import slam.cli
import importlib, pkgutil, slam
for m in pkgutil.walk_packages(slam.__path__, "slam."):
    if m.name.endswith("__main__"):
        continue  # importing it runs the CLI
    try:
        importlib.import_module(m.name)
    except Exception:
        pass
import resource
calls = {{n: [] for n in {timed!r}}}  # (seconds, the thread's minor faults) per call
lock = threading.Lock()
originals = {{}}
for mod in list(sys.modules.values()):
    for n in {timed!r}:
        f = getattr(mod, n, None)
        if callable(f) and getattr(f, "__module__", "").startswith("slam"):
            originals.setdefault(id(f), (n, f))
def wrap(n, f):
    def timed(*a, **k):
        t0, f0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        try:
            return f(*a, **k)
        finally:
            dt, df = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - f0
            with lock:
                calls[n].append((dt, df))
    return timed
wrapped = {{i: wrap(n, f) for i, (n, f) in originals.items()}}
for mod in list(sys.modules.values()):
    for n in {timed!r}:
        f = getattr(mod, n, None)
        if f is not None and id(f) in wrapped:
            setattr(mod, n, wrapped[id(f)])
rc = slam.cli.main({argv!r})
faults = sum(resource.getrusage(w).ru_minflt for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
res = {{n: {{"s": sum(c[0] for c in v), "calls": len(v), "minor_faults": sum(c[1] for c in v),
             "each_s": [c[0] for c in v]}} for n, v in calls.items()}}
res["minor_faults"] = faults
json.dump(res, open({out!r}, "w"))
sys.exit(rc)
"""


def run_variant(v: dict, out: Path, repeat: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        timers = Path(tmp) / "timers.json"
        argv = ["run", "--quiet", "--no-mesh", "--out", str(run_dir), *v["args"]]
        code = CHILD.format(checkout=v["checkout"], timed=TIMED, argv=argv, out=str(timers))
        env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=v["checkout"])
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", code], cwd=v["checkout"], env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            raise SystemExit(f"frame_breakdown: {v['name']} failed:\n{p.stderr[-3000:]}")
        t = json.loads(timers.read_text())
        m = json.loads((run_dir / "metrics.json").read_text())
    n = m["num_frames"]
    icp, track, mapping = t["icp_relative_pose"], t["track_frame"], t["map_frame"]
    if not mapping["calls"] and m.get("mapping_calls"):  # the mapper ran in its own process: its own count
        mapping = {"s": m["mapping_s"], "calls": m["mapping_calls"]}
    kinds = {"icp": icp, "tracking": track, "mapping": mapping}
    return {"variant": v["name"], "repeat": repeat, "frames": n, "wall_s": wall, "ate_rmse_cm": 100 * m["ate_rmse_m"],
            "fpt_s": m["fpt_s"], "loop_s": m.get("loop_s"), "per_frame": {
                "icp_s": icp["s"] / n, "tracking_s": track["s"] / n, "mapping_s": mapping["s"] / n,
                "wait_s": (m.get("mapping_wait_s") or 0.0) / n, "loop_s": (m.get("loop_s") or float("nan")) / n},
            "minor_faults_per_frame": t.get("minor_faults", 0) / n,
            "calls": {"icp": icp["calls"], "tracking": track["calls"], "mapping": mapping["calls"]},
            "per_call_s": {"icp": icp["s"] / max(icp["calls"], 1), "tracking": track["s"] / max(track["calls"], 1),
                           "mapping": mapping["s"] / max(mapping["calls"], 1)},
            "median_call_after_first_s": {k: statistics.median(c["each_s"][1:]) if len(c.get("each_s", [])) > 1
                                          else float("nan") for k, c in kinds.items()},
            "minor_faults_per_call": {k: c.get("minor_faults", float("nan")) / max(c["calls"], 1)
                                      for k, c in kinds.items()}}


def table(runs: list[dict], names: list[str]) -> str:
    lines = ["| variant | runs | per frame: loop | tracking | ICP | mapping (calls / frame) | waiting | minor faults "
             "| FPT | ATE cm |", "|---|---|---|---|---|---|---|---|---|---|"]
    base = None
    for name in names:
        rs = [r for r in runs if r["variant"] == name]
        med = {k: statistics.median(r["per_frame"][k] for r in rs) for k in rs[0]["per_frame"]}
        fpt = statistics.median(r["fpt_s"] for r in rs)
        base = base or fpt
        calls = rs[0]["calls"]["mapping"] / rs[0]["frames"]
        faults = statistics.median(r.get("minor_faults_per_frame", float("nan")) for r in rs)
        lines.append(f"| {name} | {len(rs)} | {med['loop_s'] * 1000:.0f} ms | {med['tracking_s'] * 1000:.0f} ms | "
                     f"{med['icp_s'] * 1000:.0f} ms | {med['mapping_s'] * 1000:.0f} ms ({calls:.2f}) | "
                     f"{med['wait_s'] * 1000:.0f} ms | {faults:.0f} | {fpt:.3f} s ({fpt / base:.2f}x) | "
                     f"{', '.join(sorted({'%.2f' % r['ate_rmse_cm'] for r in rs}))} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", action="append", required=True, help="NAME=CHECKOUT:ARGS (repeat the option)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    variants = [parse_variant(v) for v in args.variant]
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for rep in range(args.repeats):
        for v in variants:
            runs.append(run_variant(v, args.out, rep))
            r = runs[-1]["per_frame"]
            print(f"{v['name']:24s} r{rep}: FPT {runs[-1]['fpt_s']:.3f} s, tracking {r['tracking_s'] * 1000:.0f} ms, "
                  f"ICP {r['icp_s'] * 1000:.0f} ms, mapping {r['mapping_s'] * 1000:.0f} ms, waiting "
                  f"{r['wait_s'] * 1000:.0f} ms a frame, {runs[-1]['minor_faults_per_frame']:.0f} minor faults a frame "
                  f"({runs[-1]['minor_faults_per_call']['mapping']:.0f} a mapping call), median mapping call "
                  f"after the first {runs[-1]['median_call_after_first_s']['mapping'] * 1000:.0f} ms; "
                  f"ATE {runs[-1]['ate_rmse_cm']:.2f} cm", flush=True)
    save_variant_runs(args.out, "frame_breakdown", variants, runs, table(runs, [v["name"] for v in variants]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
