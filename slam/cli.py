"""The ``lrslam`` command.

Each sub-command is one module of :mod:`slam.commands` and registers itself here through its
``register(subparsers)`` function, so this module stays a thin dispatcher.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from slam import __version__, _deps
from slam.errors import SlamInputError, SlamRunError

# module path -> it defines register(subparsers); the order is the order in --help
_COMMAND_MODULES = (
    "slam.commands.run",
    "slam.commands.live",
    "slam.commands.download",
    "slam.commands.params",
    "slam.commands.mesh",
    "slam.commands.sweep",
    "slam.commands.compare",
    "slam.commands.synth",
    "slam.commands.eval",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lrslam",
        description=(
            "LRSLAM: dense RGB-D SLAM whose scene is a low-rank signed-distance field "
            "(CP geometry + Six-axis appearance, built on tdfields). With no sub-command "
            "arguments, `lrslam run` tracks and maps the bundled synthetic room on the CPU."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  lrslam download tum fr1_rpy --to data/      # fetch a dataset, print the run command for it\n"
            "  lrslam run                                  # bundled synthetic sequence, CPU\n"
            "  lrslam run --config tum/fr1_rpy-cpu --data ../shared/data/tum_fr1_rpy --out runs/rpy\n"
            "  lrslam run --config tum/fr1_rpy-cpu-fast --data my.bag --realtime   # a ROS bag at its recorded rate\n"
            "  lrslam live --out runs/desk                   # a running RealSense; Ctrl-C writes every output\n"
            "  lrslam params --config replica/room0 representation=eslam\n"
            "  lrslam eval --trajectory runs/rpy/trajectory.txt --gt runs/rpy/trajectory_gt.txt\n"
            "  lrslam synth --out data/synth --frames 120\n"
            "  lrslam sweep --config synthetic --representation lrslam eslam --seeds 5 --out sweeps/synth\n"
            "  lrslam compare sweeps/base sweeps/new                 # B - A per configuration, 95 % intervals\n"
        ),
    )
    parser.add_argument("--version", action="version", version=f"lrslam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:  # a command module not built yet must not break the others
            if exc.name and exc.name.startswith(name.rsplit(".", 1)[0]):
                continue
            raise
        module.register(sub)
    return parser


def _parse(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """``parser.parse_args(argv)``, except that a command taking ``key=value`` overrides (one that sets
    ``overrides_anywhere``) takes them before, between and after its options, in the order given: argparse alone
    takes one run of positionals, and ``lrslam run a=1 --no-mesh b=2`` would stop at ``b=2``."""
    args, extra = parser.parse_known_args(argv)
    if extra:
        if getattr(args, "overrides_anywhere", False) and all("=" in e and not e.startswith("-") for e in extra):
            args.overrides = [*args.overrides, *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def main(argv: list[str] | None = None) -> int:
    # before any sub-command module imports them: without the slam extra, one line and exit 2
    missing = _deps.missing_dependencies()
    if missing:
        print(f"lrslam: error: {_deps.missing_message(missing)}", file=sys.stderr)
        return 2
    parser = build_parser()
    args = _parse(parser, argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except SlamInputError as exc:
        print(f"lrslam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except SlamRunError as exc:
        print(f"lrslam {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
