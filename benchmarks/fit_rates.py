"""How fast each kind fits a known SDF: mean |error| after a given number of Adam steps on the CPU.

The same problem as tests/tdfields/test_fit_sdf.py (sphere of radius 0.6 m in a 2 m box, 0.1 m cells,
8 channels, 4,096 points per step, MLP decoder with 32 hidden units), evaluated at several step counts.

    python benchmarks/fit_rates.py --out benchmarks/results/fit_rates.json --docs
    python benchmarks/fit_rates.py --lr-scaling lift --seeds 0 1     # step scales (tdfields.step_scale) from step 50

``--lr-scaling`` sets each factor's rate to ``0.02 * scale`` (``matched``) or ``0.02 * max(scale, 1)`` (``lift``),
recomputed from the factors at every step from ``--scale-from`` on (at the random initialisation the scale of CP is
about 20x here). With several ``--seeds`` each cell is the mean over them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

import tdfields
from tdfields.step_scale import MODES, rate_scales

RANKS = {"vector_matrix": 4, "cp": 8, "six_axis": 8}


def sphere_sdf(p):
    return p.norm(dim=-1) - 0.6


def run(kind: str, checkpoints: list[int], seed: int = 0, scaling: str = "none", scale_from: int = 50) -> dict:
    torch.manual_seed(seed)
    spec = {"kind": kind, "aabb": [[-1, 1]] * 3, "cell_size": 0.1, "channels": 8}
    if kind in RANKS:
        spec["rank"] = RANKS[kind]
    field = tdfields.build(spec)
    dec = tdfields.MLPDecoder(8, 1, hidden=32)
    names = [n for n, _ in field.named_parameters()]
    groups = [{"params": [p], "lr": 0.02} for p in field.parameters()]  # one group per factor: its own rate
    opt = torch.optim.Adam(groups + [{"params": dec.parameters(), "lr": 0.005}])
    g = torch.Generator().manual_seed(seed)
    xt = torch.rand(20000, 3, generator=torch.Generator().manual_seed(1234)) * 2 - 1
    errors, t0, step = {}, time.perf_counter(), 0
    for target in sorted(checkpoints):
        while step < target:
            if scaling != "none" and step >= scale_from:
                scales = rate_scales(field, scaling)
                for name, group in zip(names, groups):
                    group["lr"] = 0.02 * scales[name]
            x = torch.rand(4096, 3, generator=g) * 2 - 1
            loss = (dec(field(x)).squeeze(-1) - sphere_sdf(x)).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
        with torch.no_grad():
            errors[target] = (dec(field(xt)).squeeze(-1) - sphere_sdf(xt)).abs().mean().item()
    return {"kind": kind, "parameters": field.num_parameters(), "errors_m": errors,
            "seconds": time.perf_counter() - t0}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, nargs="+", default=[50, 100, 200, 400])
    p.add_argument("--out", type=Path)
    p.add_argument("--docs", action="store_true", help="write the table into docs/tdfields.md")
    p.add_argument("--lr-scaling", choices=MODES, default="none", help="factor learning-rate scales (default none)")
    p.add_argument("--scale-from", type=int, default=50, help="first step with scaled rates (default 50)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds; cells are their mean (default 0)")
    args = p.parse_args(argv)
    if args.docs and (args.lr_scaling != "none" or args.seeds != [0]):
        p.error("--docs writes the published table: plain rates, seed 0")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _stamp import stamp, stamp_line, write_block

    rows = []
    for k in tdfields.KINDS:
        runs = [run(k, args.steps, seed, args.lr_scaling, args.scale_from) for seed in args.seeds]
        rows.append({**runs[0], "errors_m": {s: sum(r["errors_m"][s] for r in runs) / len(runs) for s in args.steps},
                     "seconds": sum(r["seconds"] for r in runs) / len(runs), "seeds": args.seeds,
                     "lr_scaling": args.lr_scaling, "per_seed_errors_m": [r["errors_m"] for r in runs]})
    lines = [stamp_line(stamp()), "",
             "| kind | parameters | " + " | ".join(f"{s} steps" for s in sorted(args.steps)) + " | seconds |",
             "|" + "---|" * (len(args.steps) + 3)]
    for r in rows:
        errs = " | ".join(f"{r['errors_m'][s] * 1000:.1f} mm" for s in sorted(args.steps))
        lines.append(f"| {r['kind']} | {r['parameters']:,} | {errs} | {r['seconds']:.1f} |")
    text = "\n".join(lines)
    print(text)
    if args.docs:
        write_block(Path(__file__).resolve().parents[1] / "docs" / "tdfields.md", "fit-rates", text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
