"""``lrslam download``: fetch Replica, a TUM RGB-D sequence or a 7-Scenes scene into the loaders' layout (the
work is in :mod:`slam.data.download`), and print the ``lrslam run`` command that reads it."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from slam.errors import SlamInputError


def register(subparsers) -> None:
    """Add the ``download`` sub-command to ``lrslam``'s sub-parsers."""
    from slam.data.download import MIRROR_ENV, REPLICA_SCENES, SEVEN_SCENES

    p = subparsers.add_parser(
        "download",
        help="download a dataset (Replica, TUM RGB-D, 7-Scenes) in the layout `lrslam run --data` reads",
        description=(
            "Download a public RGB-D dataset into DIR, unpack it into the layout the loaders read and print the\n"
            "`lrslam run` command for it. Downloads resume where they stopped (rerun the same command), are\n"
            "checked against a known or given sha256, and a rerun after success only prints the command.\n"
            "ScanNet needs the authors' permission: `lrslam download scannet` says how to ask."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "datasets and names:\n"
            "  replica [SCENE]   NICE-SLAM's Replica.zip (all 8 scenes) -> DIR/Replica/<scene>;\n"
            f"                    SCENE: {', '.join(REPLICA_SCENES)} (default room0)\n"
            "  tum SEQUENCE      TUM RGB-D, e.g. fr1_rpy, freiburg2_xyz, rgbd_dataset_freiburg3_long_office_household\n"
            "                    -> DIR/rgbd_dataset_freiburgN_<name>\n"
            f"  7scenes SCENE     Microsoft 7-Scenes: {', '.join(SEVEN_SCENES)}\n"
            "                    -> DIR/7scenes/<scene>/seq-XX\n"
            "  scannet           prints how to request access (ScanNet Terms of Use); downloads nothing\n"
            "\nexamples:\n"
            "  lrslam download tum fr1_rpy --to data/\n"
            "  lrslam download tum fr1_rpy --to data/ --frames 125:225   # + data/rgbd_dataset_freiburg1_rpy_125_224\n"
            "  lrslam download replica room0 --to data/\n"
            "  lrslam download 7scenes chess --to data/\n"
            f"\na mirror (--mirror or ${MIRROR_ENV}) serves the same paths as the publisher, e.g.\n"
            "  <mirror>/Replica.zip, <mirror>/freiburg1/rgbd_dataset_freiburg1_rpy.tgz, <mirror>/chess.zip"
        ),
    )
    p.add_argument("dataset", metavar="DATASET", help="replica, tum, 7scenes or scannet")
    p.add_argument("scene", nargs="?", default=None, metavar="SCENE",
                   help="Replica scene, TUM sequence or 7-Scenes scene (see below)")
    p.add_argument("--to", type=Path, default=Path("data"), metavar="DIR",
                   help="folder that receives the dataset (default: data)")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="tum only: also write associated pairs A..B-1 as their own sequence folder "
                        "<sequence>_A_<B-1> (as the shared excerpts are made)")
    p.add_argument("--mirror", default=None, metavar="URL",
                   help=f"fetch from URL/<path> instead of the publisher (default: ${MIRROR_ENV} if set)")
    p.add_argument("--sha256", default=None, metavar="HEX",
                   help="expected sha256 of the archive (overrides the built-in table); a mismatch deletes it")
    p.add_argument("--keep-archive", action="store_true",
                   help="keep the downloaded archive after unpacking (default: delete it)")
    p.set_defaults(func=main)


def parse_frames(text: str) -> tuple[int, int]:
    """``"A:B"`` -> ``(A, B)`` with ``0 <= A < B``; SlamInputError otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", text)
    if not m or int(m.group(1)) >= int(m.group(2)):
        raise SlamInputError(f"--frames {text!r}: expected A:B with 0 <= A < B (pairs A..B-1), e.g. 125:225")
    return int(m.group(1)), int(m.group(2))


def main(args) -> int:
    """Run the sub-command for parsed ``args``; returns the exit status (SlamInputError for bad input)."""
    from slam.data.download import SCANNET_ACCESS, fetch, run_commands

    if args.dataset.lower() == "scannet":
        print(SCANNET_ACCESS)
        return 0
    if args.sha256 is not None and not re.fullmatch(r"[0-9a-fA-F]{64}", args.sha256):
        raise SlamInputError(f"--sha256 {args.sha256!r}: expected 64 hexadecimal digits")
    frames = parse_frames(args.frames) if args.frames is not None else None
    data = fetch(args.dataset, args.scene, args.to, mirror=args.mirror, sha256=args.sha256, frames=frames,
                 keep_archive=args.keep_archive)
    print(f"ready: {data}")
    print("next:")
    for line in run_commands(args.dataset, args.scene, data):
        print(f"  {line}")
    return 0
