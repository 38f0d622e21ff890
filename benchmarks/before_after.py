"""Frame time before / after: the same ``lrslam run`` from two checkouts (an older commit and this one), interleaved.

Each *variant* is a checkout plus ``lrslam run`` arguments. Every repeat runs every variant once, in turn
(A, B, C, A, B, C, ...), each in a fresh process with one torch thread, so slow phases of a shared machine hit
all variants alike; the table reports medians over the repeats (frame time, loop and wall seconds) and the ATE of
each run (a run is deterministic for its seed, so ATE varies only across seeds, not repeats).

Usage::

    git worktree add /tmp/before 13a210d
    python benchmarks/before_after.py --out benchmarks/results/before_after_tum --repeats 3 \\
        --variant "before=/tmp/before:--config tum/fr1_rpy-cpu --data ../shared/data/tum_fr1_rpy --no-mesh" \\
        --variant "after=.:--config tum/fr1_rpy-cpu --data ../shared/data/tum_fr1_rpy --no-mesh"

A variant is ``NAME=CHECKOUT:ARGS`` (ARGS split like a shell would). Writes ``before_after.json`` (every run) and
``before_after.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def parse_variant(text: str) -> dict:
    """``NAME=CHECKOUT:ARGS`` -> ``{name, checkout, args}`` (also used by frame_breakdown.py)."""
    prog = Path(sys.argv[0]).stem
    name, _, rest = text.partition("=")
    checkout, _, args = rest.partition(":")
    if not name or not checkout:
        raise SystemExit(f"{prog}: error: a variant is NAME=CHECKOUT:ARGS, got {text!r}")
    path = Path(checkout).resolve()
    if not (path / "slam").is_dir():
        raise SystemExit(f"{prog}: error: {path} is not a checkout of this project (no slam/)")
    return {"name": name, "checkout": str(path), "args": absolute_paths(shlex.split(args))}


def save_variant_runs(out: Path, stem: str, variants: list[dict], runs: list[dict], table: str, **extra) -> None:
    """Write ``out/{stem}.json`` (stamp, command line, ``extra``, the variants and every run) and ``out/{stem}.md``
    (``table``), and print the table: the outputs of frame_breakdown.py."""
    from _stamp import stamp

    record = {"stamp": stamp(), "command": " ".join(sys.argv), **extra, "variants": variants, "runs": runs}
    (out / f"{stem}.json").write_text(json.dumps(record, indent=1) + "\n")
    (out / f"{stem}.md").write_text(table + "\n")
    print(table)


# options whose value is a path: a run starts in its own checkout, so a relative one is made absolute here, where
# it was written (`--data ../shared/...` from the main checkout means the same folder for a worktree in /tmp)
PATH_OPTIONS = ("--data", "--config", "--resume")


def absolute_paths(args: list[str]) -> list[str]:
    """``args`` with the value of every :data:`PATH_OPTIONS` option that names an existing file or folder made
    absolute (a preset name such as ``tum/fr1_rpy-cpu`` is left as it is)."""
    out = list(args)
    for i, a in enumerate(out[:-1]):
        if a in PATH_OPTIONS and Path(out[i + 1]).exists():
            out[i + 1] = str(Path(out[i + 1]).resolve())
    return out


def run_variant(v: dict, out: Path, repeat: int) -> dict:
    run_dir = out / "runs" / f"{v['name']}-r{repeat}"
    cmd = [sys.executable, "-m", "slam.cli", "run", "--quiet", "--out", str(run_dir), *v["args"]]
    env = dict(os.environ, PYTHONPATH=v["checkout"], OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=v["checkout"], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        return {"variant": v["name"], "repeat": repeat, "error": p.stderr.strip().splitlines()[-1:]}
    m = json.loads((run_dir / "metrics.json").read_text())
    rec = {"variant": v["name"], "repeat": repeat, "fpt_s": m["fpt_s"], "loop_s": m.get("loop_s"), "wall_s": wall,
           "ate_rmse_cm": None if m.get("ate_rmse_m") is None else 100 * m["ate_rmse_m"],
           "tracking_iters_mean": m.get("tracking_iters_mean"), "num_frames": m["num_frames"]}
    print(f"{v['name']} repeat {repeat}: FPT {rec['fpt_s']:.3f} s, wall {wall:.1f} s, ATE {rec['ate_rmse_cm']}",
          file=sys.stderr, flush=True)
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", action="append", required=True, help="NAME=CHECKOUT:ARGS (repeatable)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    if args.repeats < 1:
        raise SystemExit("before_after: error: --repeats must be >= 1")
    variants = [parse_variant(v) for v in args.variant]
    out = Path(args.out).resolve()  # the runs start in their checkouts: a relative --out would land in each
    out.mkdir(parents=True, exist_ok=True)
    runs = [run_variant(v, out, r) for r in range(args.repeats) for v in variants]
    sys.path.insert(0, str(ROOT))
    from slam.engine.runtime import cpu_name

    stamp = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "cpu": cpu_name(), "repeats": args.repeats}
    rows = []
    for v in variants:
        rs = [r for r in runs if r["variant"] == v["name"] and "error" not in r]
        if not rs:
            rows.append({"variant": v["name"], "error": [r.get("error") for r in runs if r["variant"] == v["name"]]})
            continue
        med = lambda key: statistics.median(r[key] for r in rs)  # noqa: E731
        rows.append({"variant": v["name"], "checkout": v["checkout"], "args": " ".join(v["args"]),
                     "fpt_s": med("fpt_s"), "loop_s": med("loop_s"), "wall_s": med("wall_s"),
                     "fpt_runs_s": [round(r["fpt_s"], 3) for r in rs], "ate_rmse_cm": rs[0]["ate_rmse_cm"],
                     "tracking_iters_mean": rs[0]["tracking_iters_mean"]})
    (out / "before_after.json").write_text(json.dumps({"stamp": stamp, "rows": rows, "runs": runs}, indent=2))
    base = next((r for r in rows if "fpt_s" in r), None)
    lines = [f"Measured {stamp['date']} on {stamp['cpu']}, 1 thread per run, medians of {args.repeats} interleaved "
             "runs (`python benchmarks/before_after.py`).", "",
             "| variant | lrslam run arguments | FPT s (median) | runs | vs first | loop s | wall s | ATE RMSE cm |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "fpt_s" not in r:
            lines.append(f"| {r['variant']} | failed: {r['error']} | | | | | | |")
            continue
        ratio = r["fpt_s"] / base["fpt_s"]
        ate = "-" if r["ate_rmse_cm"] is None else f"{r['ate_rmse_cm']:.2f}"
        runs_s = " / ".join(map(str, r["fpt_runs_s"]))
        lines.append(f"| {r['variant']} | `{r['args']}` | {r['fpt_s']:.3f} | {runs_s} | {ratio:.2f} | {r['loop_s']:.1f} "
                     f"| {r['wall_s']:.1f} | {ate} |")
    (out / "before_after.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
