"""How each decomposition's size grows with the scene: parameters and measured peak training memory.

Sweeps the side length L of a cubic scene over (at least) a decade at a fixed cell size, so the samples per
axis n grow linearly with L. For every kind and L, a fresh worker process builds the field, runs a few
Adam training steps on a tracking-sized batch (40k points) and reports its peak memory: on the CPU the rise
of the process's peak resident set (``ru_maxrss``) over a baseline taken just before the field is built, on
CUDA ``torch.cuda.max_memory_allocated``. Growth exponents are least-squares slopes in log-log space, fitted
on the largest sizes (where the field, not the fixed per-point intermediates, dominates).

Writes ``memory_growth.csv``, ``memory_growth.json`` and ``memory_growth.png`` to ``--out`` and, with
``--docs``, refreshes the table in docs/benchmarks.md between its markers.

    python benchmarks/memory_growth.py --out benchmarks/results --docs
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np

KINDS = {  # kind -> (rank, colour, label)
    "dense_grid": (None, "#d62728", "dense grid"),
    "triplane": (None, "#ff7f0e", "tri-plane"),
    "vector_matrix": (4, "#9467bd", "VM (k=4)"),
    "cp": (4, "#2ca02c", "CP (k=4)"),
    "six_axis": (4, "#1f77b4", "Six-axis (k=4)"),
}
ROOT = Path(__file__).resolve().parents[1]


def worker(kind: str, side: float, cell: float, channels: int, points: int, steps: int, device: str,
           strategy: str | None) -> dict:
    import torch

    import tdfields

    torch.manual_seed(0)
    dev = torch.device(device)
    g = torch.Generator().manual_seed(0)
    x = (torch.rand(points, 3, generator=g) * side).to(dev)
    target = torch.randn(points, channels, generator=g).to(dev)
    rank, _, _ = KINDS[kind]
    spec = {"kind": kind, "aabb": [[0, side]] * 3, "cell_size": cell, "channels": channels}
    if rank:
        spec["rank"] = rank
    if strategy:
        spec["strategy"] = strategy

    def train(field, n_steps):
        opt = torch.optim.Adam(field.parameters(), lr=1e-3)
        for _ in range(n_steps):
            opt.zero_grad(set_to_none=False)
            (field(x) - target).square().mean().backward()
            opt.step()

    # warm-up on a tiny grid: the first ops load kernels and grow allocator arenas (~100 MiB of RSS on the CPU)
    # that are not the field's; the baseline is taken after them
    train(tdfields.build({**spec, "cell_size": side / 4}).to(dev), 2)
    if dev.type == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
        base = torch.cuda.memory_allocated()
    else:
        base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    field = tdfields.build(spec).to(dev)
    train(field, steps)
    if dev.type == "cuda":
        torch.cuda.synchronize()
        peak = torch.cuda.max_memory_allocated() - base
    else:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - base
    return {"kind": kind if not strategy else f"{kind}[{strategy}]", "side_m": side, "cell_m": cell,
            "n_per_axis": field.grid_shape[0], "parameters": field.num_parameters(),
            "parameter_bytes": field.memory_bytes(), "peak_training_bytes": int(peak), "complexity": field.complexity}


def fit_exponent(sides, values) -> float:
    return float(np.polyfit(np.log(sides), np.log(values), 1)[0])


def run_sweep(args) -> list[dict]:
    sides = np.geomspace(args.min_side, args.max_side, args.sizes).round(3).tolist()
    rows = []
    configs = [(k, None) for k in args.kinds]
    if "six_axis" in args.kinds:
        configs.append(("six_axis", "factors"))  # the strictly O(n)-memory evaluation path
    for kind, strategy in configs:
        for side in sides:
            n = math.floor(side / args.cell)
            if kind == "dense_grid" and n ** 3 * args.channels * 4 * 4 > args.dense_limit_gib * 2**30:
                print(f"  skip dense_grid L={side} m: {n}^3 grid over the {args.dense_limit_gib} GiB limit")
                continue
            cmd = [sys.executable, __file__, "--worker", kind, str(side), "--cell", str(args.cell), "--channels",
                   str(args.channels), "--points", str(args.points), "--steps", str(args.steps), "--device",
                   args.device] + (["--strategy", strategy] if strategy else [])
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode != 0:
                raise RuntimeError(f"worker {kind} L={side} failed:\n{out.stderr[-2000:]}")
            row = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(f"  {row['kind']:<20} L={side:6.2f} m  n={row['n_per_axis']:4d}  params={row['parameters']:>12,}  "
                  f"peak={row['peak_training_bytes'] / 2**20:9.1f} MiB", flush=True)
    return rows


def exponents(rows, fit_last: int) -> dict:
    out = {}
    for kind in dict.fromkeys(r["kind"] for r in rows):
        rs = sorted((r for r in rows if r["kind"] == kind), key=lambda r: r["side_m"])[-fit_last:]
        s = [r["side_m"] for r in rs]
        out[kind] = {"parameters": fit_exponent(s, [r["parameters"] for r in rs]),
                     "peak_training_memory": fit_exponent(s, [max(r["peak_training_bytes"], 1) for r in rs]),
                     "complexity": rs[0]["complexity"]}
    return out


def plot(rows, exps, path: Path, stamp_text: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for kind, e in exps.items():
        base = kind.split("[")[0]
        _, colour, label = KINDS[base]
        if "[" in kind:
            label += " " + kind[kind.index("["):]
        rs = sorted((r for r in rows if r["kind"] == kind), key=lambda r: r["side_m"])
        s = [r["side_m"] for r in rs]
        style = "--" if "[" in kind else "-"
        if "[" not in kind:
            axes[0].loglog(s, [r["parameters"] for r in rs], style, marker="o", color=colour,
                           label=f"{label}: slope {e['parameters']:.2f}")
        axes[1].loglog(s, [r["peak_training_bytes"] / 2**20 for r in rs], style, marker="o", color=colour,
                       label=f"{label}: slope {e['peak_training_memory']:.2f}")
    axes[0].set(title="parameters", xlabel="scene side L (m)", ylabel="parameters")
    axes[1].set(title="peak training memory (Adam, 40k-point batch)", xlabel="scene side L (m)", ylabel="MiB")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(stamp_text, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)


def markdown(rows, exps, stamp_text: str) -> str:
    lines = [stamp_text, "", "| kind | complexity | params slope | memory slope | params at largest L | peak MiB at largest L |",
             "|---|---|---|---|---|---|"]
    for kind, e in exps.items():
        last = max((r for r in rows if r["kind"] == kind), key=lambda r: r["side_m"])
        lines.append(f"| {kind} (L={last['side_m']:g} m) | {e['complexity']} | {e['parameters']:.2f} | "
                     f"{e['peak_training_memory']:.2f} | {last['parameters']:,} | "
                     f"{last['peak_training_bytes'] / 2**20:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--worker", nargs=2, metavar=("KIND", "SIDE"), help=argparse.SUPPRESS)
    p.add_argument("--strategy", help=argparse.SUPPRESS)
    p.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    p.add_argument("--min-side", type=float, default=1.0, help="smallest scene side in metres (default 1)")
    p.add_argument("--max-side", type=float, default=20.0, help="largest scene side in metres (default 20)")
    p.add_argument("--sizes", type=int, default=7, help="number of sizes, log-spaced (default 7)")
    p.add_argument("--cell", type=float, default=0.05, help="cell size in metres (default 0.05)")
    p.add_argument("--channels", type=int, default=8, help="feature channels (default 8)")
    p.add_argument("--points", type=int, default=40_000, help="points per training step (default 40k)")
    p.add_argument("--steps", type=int, default=3, help="Adam steps per measurement (default 3)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--fit-last", type=int, default=3, help="fit slopes on this many largest sizes (default 3)")
    p.add_argument("--dense-limit-gib", type=float, default=6.0, help="skip dense grids whose training state exceeds this")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    p.add_argument("--docs", action="store_true", help="refresh docs/benchmarks.md and docs/images/memory_growth.png")
    args = p.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker[0], float(args.worker[1]), args.cell, args.channels, args.points,
                                args.steps, args.device, args.strategy)))
        return 0
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _stamp import stamp, stamp_line

    info = stamp(args.device)
    rows = run_sweep(args)
    exps = exponents(rows, args.fit_last)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "memory_growth.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (args.out / "memory_growth.json").write_text(json.dumps({"stamp": info, "settings": {
        k: v for k, v in vars(args).items() if k not in {"worker", "out", "docs", "strategy"}},
        "exponents": exps, "rows": rows}, indent=2))
    text = stamp_line(info)
    plot(rows, exps, args.out / "memory_growth.png", text)
    table = markdown(rows, exps, text)
    print(table)
    if args.docs:
        import shutil

        (ROOT / "docs" / "images").mkdir(parents=True, exist_ok=True)
        shutil.copy(args.out / "memory_growth.png", ROOT / "docs" / "images" / "memory_growth.png")
        doc = ROOT / "docs" / "benchmarks.md"
        start, end = "<!-- memory-growth:start -->", "<!-- memory-growth:end -->"
        body = doc.read_text()
        if start in body and end in body:
            doc.write_text(body[: body.index(start) + len(start)] + "\n" + table + "\n" + body[body.index(end):])
    return 0


if __name__ == "__main__":
    sys.exit(main())
