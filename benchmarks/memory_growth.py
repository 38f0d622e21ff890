"""How each decomposition's size grows with the scene: parameters and measured peak training memory.

Sweeps the side length L of a cubic scene over (at least) a decade at a fixed cell size, so the samples per
axis n grow linearly with L. For every kind and L it builds the field, runs a few Adam
training steps on a tracking-sized batch (40k points) and records torch's peak allocation (CPU: from the
profiler's allocation events; CUDA: ``max_memory_allocated``). The fixed per-point cost is measured by the same
steps on a 2x2x2 grid and subtracted, leaving the memory that grows with the scene. Growth exponents are
least-squares slopes in log-log space, fitted on the largest sizes.

Writes ``memory_growth.csv``, ``memory_growth.json`` and ``memory_growth.png`` to ``--out``; docs/results.md is then rewritten by ``python benchmarks/results_page.py``.

    python benchmarks/memory_growth.py --out benchmarks/results
"""

from __future__ import annotations

import argparse
import csv
import json
import math
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


def peak_bytes(fn, device: str) -> int:
    """Peak bytes allocated by torch while ``fn`` runs.

    CUDA: ``max_memory_allocated`` above the level before. CPU: the running sum of the profiler's allocation
    and free events (``profile_memory=True``), which is exact for torch tensors and, unlike the process's
    resident set, free of allocator and library-loading noise.
    """
    import torch

    if device.startswith("cuda"):
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
        base = torch.cuda.memory_allocated()
        fn()
        torch.cuda.synchronize()
        return torch.cuda.max_memory_allocated() - base
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
        fn()
    events = sorted((e for e in prof.profiler.kineto_results.events() if e.name() == "[memory]"),
                    key=lambda e: e.start_ns())
    current = peak = 0
    for e in events:
        current += e.nbytes()
        peak = max(peak, current)
    return peak


def measure(kind: str, side: float, cell: float | None, channels: int, x, target, steps: int, device: str,
            strategy: str | None) -> dict:
    """Build one field, train it ``steps`` Adam steps on ``x``; ``cell=None`` builds a 2x2x2 grid."""
    import torch

    import tdfields

    rank, _, _ = KINDS[kind]
    spec = {"kind": kind, "aabb": [[0, side]] * 3, "channels": channels}
    spec.update({"cell_size": cell} if cell else {"grid_shape": [2, 2, 2]})
    if rank:
        spec["rank"] = rank
    if strategy:
        spec["strategy"] = strategy
    info = {}

    def train():
        torch.manual_seed(0)
        field = tdfields.build(spec).to(device)
        opt = torch.optim.Adam(field.parameters(), lr=1e-3)
        for _ in range(steps):
            opt.zero_grad(set_to_none=False)
            (field(x) - target).square().mean().backward()
            opt.step()
        info.update(n=field.grid_shape[0], parameters=field.num_parameters(), bytes=field.memory_bytes(),
                    complexity=field.complexity)

    peak = peak_bytes(train, device)
    return {"kind": kind if not strategy else f"{kind}[{strategy}]", "side_m": side, "cell_m": cell,
            "n_per_axis": info["n"], "parameters": info["parameters"], "parameter_bytes": info["bytes"],
            "peak_training_bytes": int(peak), "complexity": info["complexity"]}


def fit_exponent(sides, values) -> float:
    return float(np.polyfit(np.log(sides), np.log(values), 1)[0])


def run_sweep(args) -> list[dict]:
    import torch

    sides = np.geomspace(args.min_side, args.max_side, args.sizes).round(3).tolist()
    g = torch.Generator().manual_seed(0)
    unit = torch.rand(args.points, 3, generator=g)
    target = torch.randn(args.points, args.channels, generator=g).to(args.device)
    rows = []
    configs = [(k, None) for k in args.kinds]
    if "six_axis" in args.kinds:
        configs.append(("six_axis", "factors"))  # the strictly O(n)-memory evaluation path
    for kind, strategy in configs:
        # the same batch through a 2x2x2 grid: the fixed per-point cost that does not grow with the scene
        batch = measure(kind, 1.0, None, args.channels, unit.to(args.device), target, args.steps, args.device,
                        strategy)["peak_training_bytes"]
        for side in sides:
            n = math.floor(side / args.cell)
            if kind == "dense_grid" and n ** 3 * args.channels * 4 * 4 > args.dense_limit_gib * 2**30:
                print(f"  skip dense_grid L={side} m: {n}^3 grid over the {args.dense_limit_gib} GiB limit")
                continue
            row = measure(kind, side, args.cell, args.channels, (unit * side).to(args.device), target, args.steps,
                          args.device, strategy)
            row["batch_bytes"] = batch
            row["growth_bytes"] = row["peak_training_bytes"] - batch
            rows.append(row)
            print(f"  {row['kind']:<20} L={side:6.2f} m  n={row['n_per_axis']:4d}  params={row['parameters']:>12,}  "
                  f"peak={row['peak_training_bytes'] / 2**20:9.2f} MiB  above batch="
                  f"{row['growth_bytes'] / 2**20:9.2f} MiB", flush=True)
    return rows


def exponents(rows, fit_last: int) -> dict:
    out = {}
    for kind in dict.fromkeys(r["kind"] for r in rows):
        rs = sorted((r for r in rows if r["kind"] == kind), key=lambda r: r["side_m"])[-fit_last:]
        s = [r["side_m"] for r in rs]
        out[kind] = {"parameters": fit_exponent(s, [r["parameters"] for r in rs]),
                     "peak_training_memory": fit_exponent(s, [r["peak_training_bytes"] for r in rs]),
                     "memory_above_batch": fit_exponent(s, [max(r["growth_bytes"], 1) for r in rs]),
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
        axes[1].loglog(s, [max(r["growth_bytes"], 1) / 2**20 for r in rs], style, marker="o", color=colour,
                       label=f"{label}: slope {e['memory_above_batch']:.2f}")
    axes[0].set(title="parameters", xlabel="scene side L (m)", ylabel="parameters")
    axes[1].set(title="peak training memory above the 40k-point batch cost (Adam)", xlabel="scene side L (m)",
                ylabel="MiB")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(stamp_text, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)


def markdown(rows, exps, stamp_text: str) -> str:
    lines = [stamp_text, "", "| kind | complexity | parameter slope | memory slope (above batch) | "
             "parameters at largest L | peak MiB at largest L | of which the 40k-point batch |",
             "|---|---|---|---|---|---|---|"]
    for kind, e in exps.items():
        last = max((r for r in rows if r["kind"] == kind), key=lambda r: r["side_m"])
        lines.append(f"| {kind} (L={last['side_m']:g} m) | {e['complexity']} | {e['parameters']:.2f} | "
                     f"{e['memory_above_batch']:.2f} | {last['parameters']:,} | "
                     f"{last['peak_training_bytes'] / 2**20:.1f} | {last['batch_bytes'] / 2**20:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    p.add_argument("--min-side", type=float, default=1.0, help="smallest scene side in metres (default 1)")
    p.add_argument("--max-side", type=float, default=20.0, help="largest scene side in metres (default 20)")
    p.add_argument("--sizes", type=int, default=7, help="number of sizes, log-spaced (default 7)")
    p.add_argument("--cell", type=float, default=0.05, help="cell size in metres (default 0.05)")
    p.add_argument("--channels", type=int, default=8, help="feature channels (default 8)")
    p.add_argument("--points", type=int, default=40_000, help="points per training step (default 40k)")
    p.add_argument("--steps", type=int, default=3, help="Adam steps per measurement (default 3)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--backend", default="torch", choices=["torch", "auto"],
                   help="tdfields kernel backend (default torch: the reference path, whose every allocation is a "
                        "torch tensor the profiler counts; the fused kernels' scratch lives outside torch)")
    p.add_argument("--fit-last", type=int, default=3, help="fit slopes on this many largest sizes (default 3)")
    p.add_argument("--dense-limit-gib", type=float, default=6.0, help="skip dense grids whose training state exceeds this")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _stamp import stamp, stamp_line
    from tdfields import kernels

    kernels.set_backend(args.backend)

    info = stamp(args.device)
    rows = run_sweep(args)
    exps = exponents(rows, args.fit_last)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "memory_growth.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (args.out / "memory_growth.json").write_text(json.dumps({"stamp": info, "settings": {
        k: v for k, v in vars(args).items() if k != "out"},
        "exponents": exps, "rows": rows}, indent=2))
    text = stamp_line(info)
    plot(rows, exps, args.out / "memory_growth.png", text)
    table = markdown(rows, exps, text)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
