"""``lrslam compare A B``: B minus A per configuration, with a 95 % interval over the seeds (slam.sweep.compare)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from slam.errors import SlamInputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "compare",
        help="is B better than A? ATE differences between two sets of seeded runs, with 95 %% intervals",
        description=(
            "Compare two result files of seeded runs (benchmarks/slam_compare.py's slam_compare.json or lrslam "
            "sweep's summary.json, or the folders holding them) configuration by configuration: mean ATE RMSE "
            "of A and B and B - A with its 95 % interval, paired by seed when both have the same seeds and ran "
            "on one machine (Welch's otherwise: a seed repeats a run exactly only on a machine that rounds the "
            "same, recorded as float_fingerprint in slam_compare.json and metrics.json). A difference whose "
            "interval contains 0 is 'unresolved', with the number of seeds a difference of that size would "
            "need; paired runs equal on every seed are 'identical'. Use it before keeping a setting: a 3-seed "
            "screen can point the other way from 5 seeds. With --representations REF CAND it compares two "
            "representations on the same configurations instead (B defaults to A): is CAND as accurate as REF at "
            "the same budget?"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  lrslam compare runs/before/slam_compare.json runs/after/slam_compare.json\n"
            "  lrslam compare sweeps/base/summary.json sweeps/new/summary.json --json diff.json\n"
            "  lrslam compare benchmarks/results/accuracy_final --representations eslam lrslam\n"
        ),
    )
    p.add_argument("a", metavar="A", help="the reference: a result file or its folder")
    p.add_argument("b", metavar="B", nargs="?", default=None,
                   help="the candidate: a result file or its folder (default: A, with --representations)")
    p.add_argument("--representations", nargs=2, default=None, metavar=("REF", "CAND"),
                   help="compare representation CAND (in B) against REF (in A) on the same configurations")
    p.add_argument("--json", default=None, metavar="OUT", help="also write every difference as JSON to OUT")
    p.set_defaults(func=main)


def main(args) -> int:
    from slam.sweep.compare import compare, machines, markdown

    if args.b is None and args.representations is None:
        raise SlamInputError("give B, or --representations REF CAND to compare two representations within A")
    b = args.a if args.b is None else args.b
    diffs = compare(args.a, b, tuple(args.representations) if args.representations else None)
    _, note = machines(args.a, b)
    print(markdown(diffs, args.a, b, note), end="")
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        rows = [dataclasses.asdict(d) | {"mean_a": d.mean_a, "mean_b": d.mean_b} for d in diffs]
        out.write_text(json.dumps({"a": str(args.a), "b": str(b), "unit": "cm", "machines": note or "one machine",
                                   "differences": rows}, indent=2))
    return 0
