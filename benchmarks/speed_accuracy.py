"""Accuracy against frame time (issue 21): one point per preset or lever, frame time from an interleaved
``benchmarks/frame_breakdown.py`` run, accuracy from 5-seed runs (``benchmarks/slam_compare.py`` or ``lrslam
sweep`` folders' ``summary.json``).

    python benchmarks/speed_accuracy.py --breakdown benchmarks/results/frame_breakdown/frame_breakdown.json \\
        --data tum_fr1_rpy_0_124 --out benchmarks/results/frame_breakdown \\
        --accuracy "now=benchmarks/results/adam_baseline/slam_compare.json" \\
        --accuracy "now, mapping by need=benchmarks/results/mapping_by_need_same_machine/slam_compare.json"

Each ``--accuracy NAME=FILE`` pairs a breakdown variant with the seeds' ATE of the runs in FILE whose data folder
ends with ``--data``. Writes ``speed_accuracy.json`` (every point: median frame time, the per-seed ATE, mean and
standard deviation) and ``speed_accuracy.png``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path


def seeds_ate(path: Path, data: str) -> list[float]:
    """The ATE (cm) of every run in a ``slam_compare.json`` (or an ``lrslam sweep`` ``summary.json``) whose data
    folder ends with ``data``, by seed."""
    d = json.loads(path.read_text())
    runs = d.get("runs") or []
    cm = (lambda r: r["ate_rmse_cm"] if r.get("ate_rmse_cm") is not None else
          (100 * r["ate_rmse_m"] if r.get("ate_rmse_m") is not None else None))
    vals = {r["seed"]: cm(r) for r in runs if str(r.get("data", "")).rstrip("/").endswith(data) and cm(r) is not None}
    if not vals:
        raise SystemExit(f"speed_accuracy: error: no run on {data!r} in {path}")
    return [vals[s] for s in sorted(vals)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--breakdown", type=Path, required=True, help="frame_breakdown.json")
    ap.add_argument("--accuracy", action="append", default=[], help="VARIANT=slam_compare.json (repeat)")
    ap.add_argument("--data", required=True, help="the data folder's name the accuracy runs are taken on")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    fb = json.loads(args.breakdown.read_text())
    points = []
    for spec in args.accuracy:
        name, _, file = spec.partition("=")
        rs = [r for r in fb["runs"] if r["variant"] == name]
        if not rs:
            raise SystemExit(f"speed_accuracy: error: no variant {name!r} in {args.breakdown}")
        ate = seeds_ate(Path(file), args.data)
        points.append({"variant": name, "fpt_s": statistics.median(r["fpt_s"] for r in rs),
                       "tracking_s": statistics.median(r["per_frame"]["tracking_s"] for r in rs),
                       "ate_cm": ate, "ate_mean_cm": statistics.fmean(ate),
                       "ate_std_cm": statistics.stdev(ate) if len(ate) > 1 else None, "accuracy_from": file})
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "speed_accuracy.json").write_text(json.dumps({"stamp": fb.get("stamp"), "data": args.data,
                                                              "points": points}, indent=1) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for p in points:
        ax.errorbar(p["fpt_s"], p["ate_mean_cm"], yerr=p["ate_std_cm"] or 0, fmt="o", capsize=3)
        ax.annotate(p["variant"], (p["fpt_s"], p["ate_mean_cm"]), textcoords="offset points", xytext=(6, 4), fontsize=8)
    ax.set_xlabel("median frame time (s, interleaved runs, 1 torch thread)")
    ax.set_ylabel("ATE RMSE (cm, mean ± std over seeds)")
    ax.set_title(f"Accuracy against frame time ({args.data})", fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.out / "speed_accuracy.png", dpi=110)
    for p in points:
        print(f"{p['variant']:34s} FPT {p['fpt_s']:.3f} s  ATE {p['ate_mean_cm']:.2f} ± {p['ate_std_cm'] or 0:.2f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
