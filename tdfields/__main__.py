"""``python -m tdfields report SPEC_OR_CHECKPOINT [--json OUT]``: size report of a field spec or checkpoint."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tdfields import __version__
from tdfields.checkpoint import load
from tdfields.config import build
from tdfields.report import report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tdfields",
        description="Inspect tensor-decomposition fields: parameters, bytes and memory growth per field.")
    parser.add_argument("--version", action="version", version=f"tdfields {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    rep = sub.add_parser("report", help="print the parameter/memory table of a YAML spec or a saved checkpoint",
                         description="Build the field described by a YAML spec (or rebuild the one saved in a "
                                     "tdfields checkpoint) and print one row per field with totals.")
    rep.add_argument("source", type=Path, help="YAML field spec (see tdfields.build) or a .pt checkpoint")
    rep.add_argument("--json", type=Path, metavar="OUT", help="also write the report as JSON")
    args = parser.parse_args(argv)
    try:
        if args.source.suffix in {".yaml", ".yml"}:
            module = build(args.source)
        else:
            payload = load(args.source)
            if payload["spec"] is None:
                raise ValueError(f"{args.source}: checkpoint holds no field spec")
            module = build(payload["spec"])
    except (ValueError, FileNotFoundError) as exc:
        print(f"python -m tdfields report: error: {exc}", file=sys.stderr)
        return 2
    rep_ = report(module)
    print(rep_)
    if args.json:
        args.json.write_text(json.dumps(rep_.as_dict(), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
