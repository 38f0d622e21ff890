"""Achieved GFLOP/s and effective memory bandwidth of the fused CPU kernels, against this CPU's measured peaks.

Peaks are measured here, not taken from a datasheet: FLOP/s from a large float32 matrix product (torch's BLAS),
bandwidth from copying a 256 MiB tensor (DRAM) and a 8 MiB one (last-level cache). Each kernel is timed alone
(median of repeats) at the paper's Replica room0 configuration on 40k uniformly random points, on the plan a
SLAM mapping query evaluates (``tdfields.plan``, as ``MultiResolution.forward`` runs it), and its work is
counted from its program: per point, every factor's ``2**d`` corner rows (``d`` axes) are read and blended
(2 FLOPs per value), the term's factors multiplied and the rank components summed. "Effective bandwidth" is the
bytes those corner rows occupy divided by the time: the gather traffic the kernel must serve, whether it comes
from cache or DRAM.

    python benchmarks/kernel_roofline.py --out benchmarks/results/kernel_roofline.json --docs
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def median_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    times.sort()
    return times[len(times) // 2]


def peaks(repeats: int) -> dict:
    import torch

    a = torch.randn(2048, 2048)
    b = torch.randn(2048, 2048)
    t = median_time(lambda: a @ b, repeats)
    flops = 2 * 2048**3 / t
    big = torch.empty(64 << 20)  # 256 MiB
    big_dst = torch.empty_like(big)
    big.fill_(1.0)
    big_dst.fill_(0.0)
    t_big = median_time(lambda: big_dst.copy_(big), repeats)
    small = torch.ones(2 << 20)  # 8 MiB
    small_dst = torch.zeros_like(small)
    t_small = median_time(lambda: small_dst.copy_(small), repeats * 10)
    return {"gflops": flops / 1e9, "dram_gbs": 2 * big.numel() * 4 / t_big / 1e9,
            "llc_gbs": 2 * small.numel() * 4 / t_small / 1e9}


def program_work(program, widths, n_points: int, itemsize: int = 4) -> tuple[float, float]:
    """(FLOPs, bytes of corner rows read) of one forward pass over ``n_points``."""
    flops = 0
    rows_bytes = 0
    for term, k in zip(program.terms, program.ranks):
        width = widths[term[0]]
        for f in term:
            corners = 1 << len(program.factor_axes[f])
            flops += 2 * corners * width
            rows_bytes += corners * width * itemsize
        flops += (len(term) - 1) * width + width  # products, then the rank sum
    return float(flops * n_points), float(rows_bytes * n_points)


def kernels_to_measure():
    """name -> (config name in conftest.CONFIGS, note)."""
    return {
        "CP geometry (rank 2, 0.24 + 0.06 m)": "geometry/lrslam-cp",
        "Six-axis appearance, composed planes (0.24 + 0.03 m)": "appearance/lrslam-six_axis",
        "Six-axis appearance, factor path (rank 16)": "appearance/lrslam-six_axis-factors",
        "tri-plane geometry (0.24 + 0.06 m)": "geometry/eslam-triplane",
        "tri-plane appearance (0.24 + 0.03 m)": "appearance/eslam-triplane",
    }


def measure(repeats: int) -> dict:
    import torch

    import tdfields
    from conftest import build, points
    from tdfields.ops import evaluate, grid_coords

    x = points()
    rows = []
    for label, name in kernels_to_measure().items():
        field = build(name)
        field.requires_grad_(False)
        # the plan a SLAM mapping query evaluates: tdfields.plan is what MultiResolution.forward runs (for Six-axis
        # the planes composed over the points' bounding box), so the lookup timed here is the one mapping runs
        plan = tdfields.plan(field, x)
        widths = tuple(t.shape[-1] for t in plan.tensors)
        with torch.no_grad():
            t = median_time(lambda: evaluate(plan.program, plan.tensors, plan.coords), repeats)
        flops, nbytes = program_work(plan.program, widths, x.shape[0])
        factor_mib = sum(t.numel() * t.element_size() for t in plan.tensors) / 2**20
        rows.append({"kernel": f"lookup: {label}", "ms": 1e3 * t, "gflops": flops / t / 1e9,
                     "gbs": nbytes / t / 1e9, "working_set_mib": factor_mib})
    # Six-axis plane composition: planning the fine appearance level as a mapping query does (Field.plan_at: its
    # three planes composed over the points' bounding box, the coordinates shifted to them)
    field = build("appearance/lrslam-six_axis")
    fine = field.levels[1]
    coords = grid_coords(x, [fine.aabb], [fine.grid_shape])
    with torch.no_grad():
        t = median_time(lambda: fine.plan_at(coords), repeats)
        planes = fine.plan_at(coords).tensors
    k, C = fine.rank, fine.channels
    flops = sum(2 * p.shape[0] * p.shape[1] * k * C for p in planes)
    nbytes = sum(4 * (p.shape[0] * p.shape[1] * C + (p.shape[0] + p.shape[1]) * k * C) for p in planes)
    rows.append({"kernel": "Six-axis plane composition (fine level, 3 planes, k=16, C=32)", "ms": 1e3 * t,
                 "gflops": flops / t / 1e9, "gbs": nbytes / t / 1e9, "working_set_mib": nbytes / 2**20})
    return {"rows": rows}


def table(result: dict) -> str:
    p, s = result["peaks"], result["stamp"]
    lines = [f"Measured {s['date']} with tdfields {s['version']}, torch {s['torch']}, on {s['cpu']}, "
             f"{s['threads']} thread(s). Measured peaks: {p['gflops']:.0f} GFLOP/s (float32 matrix product), "
             f"{p['dram_gbs']:.1f} GB/s DRAM copy, {p['llc_gbs']:.1f} GB/s cache-resident copy.", "",
             "| kernel | ms (40k points) | GFLOP/s | % of peak FLOP/s | effective GB/s | % of cache copy | "
             "working set MiB |", "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['kernel']} | {r['ms']:.2f} | {r['gflops']:.1f} | {100 * r['gflops'] / p['gflops']:.0f} % | "
                     f"{r['gbs']:.1f} | {100 * r['gbs'] / p['llc_gbs']:.0f} % | {r['working_set_mib']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1, help="torch / kernel threads (default 1)")
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "kernel_roofline.json")
    ap.add_argument("--docs", action="store_true", help="write the table into docs/benchmarks.md")
    args = ap.parse_args(argv)

    import torch

    import tdfields
    from _stamp import cpu_name, write_block

    torch.set_num_threads(args.threads)
    result = {"peaks": peaks(args.repeats), **measure(args.repeats)}
    result["stamp"] = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "version": tdfields.__version__,
                       "torch": torch.__version__, "cpu": cpu_name(), "threads": args.threads}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    text = table(result)
    print(text)
    if args.docs:
        write_block(ROOT / "docs" / "benchmarks.md", "roofline", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
