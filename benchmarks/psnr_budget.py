"""Parameters at equal PSNR (issue 23): held-out PSNR against the parameter budget for several tdfields kinds,
over seeds, and from those curves the parameters each kind needs to reach a given PSNR.

Every (budget, seed) is one ``examples/fit_radiance_field.py --compare KINDS --budget B --seed S`` process (the
kinds on the same images, rays and schedule; ``--budget`` matches the total count, fields and heads, as closely as
the kind allows: kinds with a rank spend it on rank, the tri-plane on resolution), ``--jobs`` of them at a time, one
thread each. For each kind the mean PSNR over seeds is taken at each budget; the parameters a kind needs for a
PSNR level are read off that curve, linear in log(parameters) between the two budgets around the level (levels
outside a kind's measured range are not extrapolated). The ratio column is each kind's need over the reference
kind's (``--reference``, default six_axis): above 1, the kind needs more parameters than the reference for the
same held-out PSNR.

    python benchmarks/psnr_budget.py --seeds 3 --out benchmarks/results/psnr_budget   # ~20 min on 2 cores
    python benchmarks/psnr_budget.py --budgets 20000 40000 --seeds 1 --steps 50 --out /tmp/pb   # a smoke run

Writes ``psnr_budget.json`` (every run's metrics, the per-budget means and the parameters at each level),
``psnr_budget.png`` (PSNR against parameters, mean and spread over seeds); docs/results.md is then rewritten by ``python benchmarks/results_page.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
EXAMPLE = ROOT / "examples" / "fit_radiance_field.py"


def fit(budget: int, seed: int, args, out: Path) -> list[dict]:
    """One example process: every kind at ``budget`` with ``seed``; returns its compare.json rows."""
    folder = out / "runs" / f"b{budget}_s{seed}"
    cmd = [sys.executable, str(EXAMPLE), "--compare", *args.kinds, "--budget", str(budget), "--seed", str(seed),
           "--steps", str(args.steps), "--rays", str(args.rays), "--samples", str(args.samples), "--threads", "1",
           "--size", args.size, "--frames", str(args.frames), "--out", str(folder)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise SystemExit(f"psnr_budget: {' '.join(cmd)} failed:\n{done.stderr[-2000:]}")
    return json.loads((folder / "compare.json").read_text())


def curve_means(rows: list[dict], kinds: list[str], budgets: list[int]) -> dict:
    """``{kind: [{budget, parameters, psnr_mean, psnr_std, psnr}]}``, budgets ascending."""
    out = {}
    for kind in kinds:
        pts = []
        for b in budgets:
            rs = [r for r in rows if r["kind"] == kind and r["budget"] == b]
            psnr = [r["psnr"] for r in rs]
            pts.append({"budget": b, "parameters": round(statistics.fmean(r["parameters"] for r in rs)),
                        "psnr": psnr, "psnr_mean": statistics.fmean(psnr),
                        "psnr_std": statistics.stdev(psnr) if len(psnr) > 1 else None})
        out[kind] = pts
    return out


def parameters_at(points: list[dict], level: float) -> float | None:
    """Parameters where the mean PSNR curve first reaches ``level`` (linear in log parameters between budgets);
    None where the curve never reaches it or starts above it (no extrapolation)."""
    if points[0]["psnr_mean"] > level:
        return None
    for a, b in zip(points, points[1:]):
        if a["psnr_mean"] <= level <= b["psnr_mean"] and b["psnr_mean"] > a["psnr_mean"]:
            t = (level - a["psnr_mean"]) / (b["psnr_mean"] - a["psnr_mean"])
            return math.exp(math.log(a["parameters"]) + t * (math.log(b["parameters"]) - math.log(a["parameters"])))
    return None


def levels_table(curves: dict, levels: list[float], reference: str) -> list[dict]:
    rows = []
    for level in levels:
        need = {k: parameters_at(pts, level) for k, pts in curves.items()}
        ref = need.get(reference)
        ratio = {k: (None if v is None or ref is None else v / ref) for k, v in need.items()}
        rows.append({"psnr": level, "parameters": need, "ratio_to_reference": ratio})
    return rows


def plot(curves: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, ax = plt.subplots(figsize=(6, 4))
    for kind, pts in curves.items():
        x = [p["parameters"] for p in pts]
        y = [p["psnr_mean"] for p in pts]
        err = [p["psnr_std"] or 0.0 for p in pts]
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=kind)
    ax.set_xscale("log")
    ticks = sorted({p["budget"] for pts in curves.values() for p in pts})
    ax.set_xticks(ticks, [f"{b // 1000}k" for b in ticks])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("parameters (fields and heads)")
    ax.set_ylabel("held-out PSNR (dB), mean ± std over seeds")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def markdown(result: dict) -> str:
    from _stamp import stamp_line

    s = result["settings"]
    kinds = s["kinds"]
    lines = [f"{stamp_line(result['stamp'])} Synthetic room {s['size']}, {s['frames']} frames (every 8th held out), "
             f"{s['steps']} steps of {s['rays']} rays x {s['samples']} samples, seeds 0-{s['seeds'] - 1}, "
             "one thread per run.", "",
             f"`{result['command']}`", "",
             "| budget | " + " | ".join(f"{k} parameters | {k} PSNR dB" for k in kinds) + " |",
             "|---|" + "---|---|" * len(kinds)]
    for i, b in enumerate(s["budgets"]):
        cells = []
        for k in kinds:
            p = result["curves"][k][i]
            sd = "" if p["psnr_std"] is None else f" ± {p['psnr_std']:.2f}"
            cells += [f"{p['parameters']:,}", f"{p['psnr_mean']:.2f}{sd}"]
        lines.append(f"| {b:,} | " + " | ".join(cells) + " |")
    ref = s["reference"]
    lines += ["", f"Parameters needed for a held-out PSNR (read off the mean curves; in brackets: over {ref}'s):", "",
              "| PSNR dB | " + " | ".join(kinds) + " |", "|---|" + "---|" * len(kinds)]
    for row in result["levels"]:
        cells = []
        for k in kinds:
            v, r = row["parameters"][k], row["ratio_to_reference"][k]
            cells.append("-" if v is None else f"{v:,.0f}" + ("" if k == ref or r is None else f" ({r:.2f}x)"))
        lines.append(f"| {row['psnr']:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kinds", nargs="+", default=["six_axis", "triplane", "vector_matrix"])
    ap.add_argument("--reference", default="six_axis", help="the kind the others' needs are divided by")
    ap.add_argument("--budgets", type=int, nargs="+", default=[25000, 50000, 100000, 200000, 400000])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--rays", type=int, default=512)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--size", default="60x80", help="synthetic room image size HxW")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--levels", type=float, nargs="+", help="PSNR levels (default: every 0.5 dB all kinds reach)")
    ap.add_argument("--jobs", type=int, default=2, help="example processes at a time (one thread each)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "psnr_budget")
    ap.add_argument("--from-json", type=Path, help="measure nothing: table and figure from this JSON")
    args = ap.parse_args(argv)
    if args.from_json:
        return publish(json.loads(args.from_json.read_text()), args.from_json.parent)
    if args.reference not in args.kinds:
        ap.error(f"--reference {args.reference} is not one of --kinds")
    if len(args.budgets) < 2 or sorted(args.budgets) != args.budgets:
        ap.error("--budgets: at least two, ascending")
    args.out.mkdir(parents=True, exist_ok=True)
    from _stamp import stamp

    t0 = time.perf_counter()
    jobs = [(b, s) for s in range(args.seeds) for b in args.budgets]
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda bs: fit(*bs, args, args.out), jobs))
    rows = []
    for (b, s), rs in zip(jobs, results):
        rows += [{"budget": b, "seed": s, **{k: r[k] for k in ("kind", "psnr", "ssim", "parameters", "seconds",
                                                                "resolution", "fields")}} for r in rs]
    curves = curve_means(rows, args.kinds, args.budgets)
    levels = args.levels
    if not levels:  # every half dB inside the range that every kind's mean curve covers
        lo = max(pts[0]["psnr_mean"] for pts in curves.values())
        hi = min(max(p["psnr_mean"] for p in pts) for pts in curves.values())
        levels = [x / 2 for x in range(math.ceil(2 * lo), math.floor(2 * hi) + 1)]
    st = stamp()
    st["torch_threads"] = 1  # each example process runs one thread
    command = "python benchmarks/psnr_budget.py " + " ".join(argv if argv is not None else sys.argv[1:])
    result = {"stamp": st, "command": command.strip(), "seconds": round(time.perf_counter() - t0, 1),
              "settings": {**{k: v for k, v in vars(args).items() if k not in ("out", "levels", "jobs")},
                           "levels": levels},
              "runs": rows, "curves": curves, "levels": levels_table(curves, levels, args.reference)}
    (args.out / "psnr_budget.json").write_text(json.dumps(result, indent=1))
    return publish(result, args.out)


def publish(result: dict, out: Path) -> int:
    """The figure next to the JSON, the tables printed."""
    s = result["settings"]
    plot(result["curves"], out / "psnr_budget.png",
         f"Synthetic room {s['size']}, {s['steps']} steps, {s['seeds']} seeds")
    text = markdown(result)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
