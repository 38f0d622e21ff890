"""How much arithmetic one tracking and one mapping iteration do, and how fast it runs (issue 21: "count it
properly before you set your own targets").

It maps the first ``--warm-frames`` frames of a sequence (as ``benchmarks/profile_slam.py`` does), then runs one
whole tracking call and one whole mapping call on the next frame twice: once counting, once timed (median of
``--repeats``, the map restored after each mapping call). Counted per iteration:

* field lookups: every ``tdfields.ops.evaluate`` of a field query, its work from the program
  (``benchmarks/kernel_roofline.py``'s ``program_work``: every factor's corner rows read and blended, the
  products and the rank sum), times the points queried; queries under autograd count their backward as twice
  the forward (the usual convention: a gradient to the inputs and one to the factors);
* Six-axis plane composition: ``2 n_a n_b k C`` per composed plane region, backward twice that (mapping composes
  the batch's region at every iteration; tracking composes the planes once per call, counted here spread over its
  iterations);
* everything torch runs (the decoders, the pose and ray matrices, forward and backward), with
  ``torch.utils.flop_counter.FlopCounterMode``, which counts matrix products (elementwise work is not counted:
  it is memory-bound, and in these iterations small next to the products).

GFLOP/s achieved is that count over the timed iteration; the peak is a large float32 matrix product on this CPU
(``kernel_roofline.peaks``). The gap between the two is what a faster way of running the *same* iteration (fused
kernels, less Python) could win at most; everything beyond it needs less work per frame.

    python benchmarks/iteration_flops.py --out benchmarks/results/iteration_flops.json --docs
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


@contextlib.contextmanager
def counting():
    """Counts field-lookup and composition FLOPs (forward, backward) while active; yields the totals dict."""
    import torch

    import tdfields.field as field_mod
    import tdfields.six_axis as six_mod
    from kernel_roofline import program_work

    totals = {"lookup_fwd": 0.0, "lookup_bwd": 0.0, "compose_fwd": 0.0, "compose_bwd": 0.0, "lookup_points": 0}
    evaluate, compose = field_mod.evaluate, six_mod.compose_plane

    def differentiable(*tensors) -> bool:
        return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)

    def counted_evaluate(program, tensors, coords):
        widths = tuple(t.shape[-1] for t in tensors)
        flops, _ = program_work(program, widths, coords.shape[1])
        totals["lookup_fwd"] += flops
        totals["lookup_points"] += coords.shape[1]
        if differentiable(coords, *tensors):
            totals["lookup_bwd"] += 2 * flops
        return evaluate(program, tensors, coords)

    def counted_compose(u, v, rank, read_at=None, rows=None):
        # every cell of the box (u.shape[1] = rank x channels); the CPU kernel composes only the cells read_at reads
        # and its backward skips the zero cells, so for a batch that reads part of the box this is an upper bound
        n_a, n_b = (u.shape[0], v.shape[0]) if rows is None else (rows[0][1] - rows[0][0], rows[1][1] - rows[1][0])
        flops = 2.0 * n_a * n_b * u.shape[1]
        totals["compose_fwd"] += flops
        if differentiable(u, v):
            totals["compose_bwd"] += 2 * flops
        return compose(u, v, rank, read_at=read_at, rows=rows)

    field_mod.evaluate, six_mod.compose_plane = counted_evaluate, counted_compose
    try:
        yield totals
    finally:
        field_mod.evaluate, six_mod.compose_plane = evaluate, compose


def measure(preset: str, data: str, representation: str, warm_frames: int, repeats: int, overrides) -> dict:
    from torch.utils.flop_counter import FlopCounterMode

    from profile_slam import warm_calls

    _, track_call, mapping = warm_calls(preset, [f"representation={representation}", "parallel=false",
                                                   *([f"data.path={data}"] if data else []), *overrides], warm_frames)

    def track():
        return track_call().iters

    rows = {}
    for name, fn in (("tracking", track), ("mapping", mapping)):
        fn()  # warm-up: kernels compiled, caches filled
        with counting() as fields, FlopCounterMode(display=False) as torch_ops:
            iters = fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        per = {key: v / iters for key, v in fields.items()}
        torch_flops = torch_ops.get_total_flops() / iters
        total = per["lookup_fwd"] + per["lookup_bwd"] + per["compose_fwd"] + per["compose_bwd"] + torch_flops
        ms = 1e3 * statistics.median(times) / iters
        rows[name] = {"iterations": iters, "points_per_iteration": round(per["lookup_points"]),
                      "gflop": {"field lookups (forward)": per["lookup_fwd"] / 1e9,
                                "field lookups (backward)": per["lookup_bwd"] / 1e9,
                                "plane composition": (per["compose_fwd"] + per["compose_bwd"]) / 1e9,
                                "torch matrix products (decoders, poses)": torch_flops / 1e9},
                      "gflop_total": total / 1e9, "ms_per_iteration": ms, "gflops_achieved": total / ms / 1e6,
                      "ms_times": [1e3 * t / iters for t in times]}
    return rows


def table(result: dict) -> str:
    from _stamp import stamp_line

    peak = result["peaks"]["gflops"]
    lines = [f"{stamp_line(result['stamp'])} Peak: {peak:.0f} GFLOP/s (float32 matrix product, this CPU, "
             f"{result['stamp']['torch_threads']} thread). {result['setup']}.", "",
             f"`{result['command']}`", "",
             "| representation | phase | points queried / iter (both fields) | GFLOP / iter (lookups fwd + bwd, "
             "composition, matrix products) | ms / iter | GFLOP/s | % of peak | ms / iter at peak |",
             "|---|---|---|---|---|---|---|---|"]
    for rep, rows in result["rows"].items():
        for phase, r in rows.items():
            g = r["gflop"]
            parts = " + ".join(f"{v:.3f}" for v in g.values())
            lines.append(f"| {rep} | {phase} | {r['points_per_iteration']:,} | {r['gflop_total']:.3f} ({parts}) | "
                         f"{r['ms_per_iteration']:.1f} | {r['gflops_achieved']:.1f} | "
                         f"{100 * r['gflops_achieved'] / peak:.0f} % | {r['gflop_total'] / peak * 1e3:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="tum/fr1_rpy-cpu")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "tum_fr1_rpy_0_124"),
                    help="dataset folder ('' for the preset's own)")
    ap.add_argument("--representations", nargs="+", default=["lrslam", "eslam"])
    ap.add_argument("--warm-frames", type=int, default=8)
    ap.add_argument("--first-iters", type=int, default=100, help="first-frame warm-up iterations (default 100)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "iteration_flops.json")
    ap.add_argument("--docs", action="store_true", help="write the table into docs/benchmarks.md (block "
                    "iteration-flops)")
    ap.add_argument("overrides", nargs="*", metavar="key=value")
    args = ap.parse_args(argv)

    import torch

    from _stamp import stamp, write_block
    from kernel_roofline import peaks

    torch.set_num_threads(1)
    overrides = [f"mapping.iters_first={args.first_iters}", *args.overrides]
    rows = {rep: measure(args.preset, args.data, rep, args.warm_frames, args.repeats, overrides)
            for rep in args.representations}
    st = stamp()
    result = {"stamp": st, "command": "python benchmarks/iteration_flops.py " + " ".join(
                  argv if argv is not None else sys.argv[1:]),
              "setup": f"{args.preset} on {Path(args.data).name or 'its data'}, frame {args.warm_frames} after "
                       f"{args.warm_frames} mapped, one thread, medians of {args.repeats}",
              "peaks": peaks(5), "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    text = table(result)
    print(text)
    if args.docs:
        write_block(ROOT / "docs" / "benchmarks.md", "iteration-flops", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
