"""``lrslam sweep``: presets x representations x seeds, one Ray task and one output folder per run, a summary."""

from __future__ import annotations

import argparse
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="run presets x representations x seeds on Ray and summarise them (mean ± std)",
        description=(
            "Run every (preset, representation, seed) combination as one Ray task (a local Ray by default, a "
            "cluster with --address), each into DIR/<preset>-<representation>-s<seed>, and write "
            "DIR/summary.json (every run's record) and DIR/summary.md (mean ± std per preset and representation). "
            "Failed runs are recorded with their error; running the same command again skips the finished runs. "
            "Needs Ray (the sweep extra)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  lrslam sweep --config synthetic --representation lrslam eslam --seeds 5 --out sweeps/synth\n"
            "  lrslam sweep --config tum/fr1_rpy-cpu=../shared/data/tum_fr1_rpy --representation lrslam cp_cp \\\n"
            "      --seeds 3 --out sweeps/rpy --no-mesh tracking.iters=10\n"
            "  lrslam sweep --config synthetic --representation lrslam --seeds 5 --out sweeps/c --address ray://head:10001\n"
            "key=value overrides go after the other options (or after --); they apply to every run."
        ),
    )
    p.add_argument("--config", nargs="+", required=True, metavar="PRESET[=DATA]",
                   help="presets (names or YAML files), each optionally with its data folder as PRESET=DATA")
    p.add_argument("--representation", nargs="+", required=True, metavar="REP",
                   help="representations (lrslam, eslam, cp_cp, sa_sa, sa_cp, vm_sa)")
    p.add_argument("--seeds", type=int, required=True, metavar="N", help="runs per combination, seeds 0..N-1")
    p.add_argument("--out", required=True, metavar="DIR", help="sweep folder (run folders and the summary)")
    p.add_argument("--data", default=None, metavar="PATH", help="data folder for presets given without =DATA")
    p.add_argument("--address", default=None, metavar="RAY_ADDRESS",
                   help="Ray cluster to run on (ray.init(address=...)); default: start a local Ray")
    p.add_argument("--cpus-per-run", type=int, default=1, metavar="K",
                   help="CPUs Ray gives each loop thread of a run, also its torch thread count (default 1); "
                        "a run in parallel mode (tracker + mapper threads) gets twice K")
    p.add_argument("--num-cpus", type=int, default=None, metavar="N",
                   help="CPUs of the local Ray (default: all of this machine's)")
    p.add_argument("--no-mesh", action="store_true", help="skip mesh extraction and reconstruction metrics")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides for every run")
    p.set_defaults(func=main)


def _hint_misplaced_overrides(configs: list[str]) -> None:
    """``--config a tracking.iters=2`` swallows the override as a preset; say so instead of 'unknown preset'."""
    from slam.config import list_presets
    from slam.errors import SlamInputError
    from slam.sweep import split_preset

    known = set(list_presets())
    for item in configs:
        preset, data = split_preset(item)
        if data is not None and "." in preset and preset not in known and not preset.endswith((".yaml", ".yml")):
            raise SlamInputError(f"--config {item}: looks like a key=value override; put overrides after the "
                                 f"other options or after --")


def main(args) -> int:
    import logging

    from slam.sweep import RayEngine, execute, plan, require_ray

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    _hint_misplaced_overrides(args.config)
    if args.num_cpus is not None and args.num_cpus < 1:
        from slam.errors import SlamInputError

        raise SlamInputError(f"--num-cpus must be >= 1, got {args.num_cpus}")
    require_ray()
    specs = plan(args.config, args.representation, args.seeds, args.out, overrides=args.overrides,
                 threads=args.cpus_per_run, mesh=not args.no_mesh, data=args.data)
    print(f"sweep: {len(specs)} runs into {args.out}", file=sys.stderr)
    engine = RayEngine(address=args.address, cpus_per_run=args.cpus_per_run, num_cpus=args.num_cpus)
    summary = execute(specs, engine, out=args.out)
    from slam.sweep import summary_markdown

    print(summary_markdown(summary))
    failed = sum(r["status"] != "ok" for r in summary["runs"])
    if failed:
        print(f"{failed} of {len(specs)} runs failed; see {args.out}/summary.json", file=sys.stderr)
        return 1
    return 0
