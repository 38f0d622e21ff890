"""``lrslam live``: SLAM on a running camera (an Intel RealSense), the newest frame processed each time the system
is free, every frame received recorded as a TUM folder to run again offline."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from slam.errors import SlamInputError

#: how a ``--camera`` name opens its camera (tests put a stand-in here)
CAMERAS = {"realsense": lambda args: _realsense(args)}


def _realsense(args):
    from slam.data.live import RealSense

    return RealSense(width=args.width, height=args.height, fps=args.fps)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "live",
        help="run SLAM on a live camera (RealSense), recording what it receives",
        description=(
            "Track and map what a running camera sees. Frames are taken as the camera delivers them: each time the "
            "system is free it takes the newest frame and drops the ones it missed (as lrslam run --realtime does "
            "with a recorded folder). Ctrl-C or SIGTERM stops the camera; the frames taken are finished and every "
            "output is written to --out (trajectory.txt, frames.csv, mesh.ply, metrics.json with frames processed "
            "and dropped and the latency from a frame's arrival to its pose); a second Ctrl-C stops at once. "
            "Every frame received is recorded in the TUM layout (--record, default OUT/frames) so the run can be "
            "redone offline: lrslam run --data OUT/frames."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:  lrslam live --out runs/desk --rerun-connect     (pip install -e \".[realsense,viewer]\")",
    )
    p.add_argument("--camera", default="realsense", choices=sorted(CAMERAS), help="camera (default: realsense)")
    p.add_argument("--config", default="tum",
                   help="preset or YAML for the tracker and mapper (default: tum); its data settings do not apply: the "
                        "camera gives the images and intrinsics")
    p.add_argument("--profile", default=None,
                   help="realtime, quality, paper or a YAML file (default: realtime on the CPU, paper on CUDA)")
    p.add_argument("--out", default="runs/live", help="output folder (default: runs/live)")
    p.add_argument("--record", default=None, metavar="DIR",
                   help="where to record the frames received (default: OUT/frames)")
    p.add_argument("--no-record", action="store_true", help="do not record the frames received")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="stop after N frames received")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--device", default=None, choices=["cpu", "cuda"], help="torch device (default: the config's)")
    p.add_argument("--no-mesh", action="store_true", help="skip mesh extraction")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--rerun", metavar="FILE.rrd", default=None, help="log the run to a Rerun recording")
    p.add_argument("--rerun-connect", metavar="ADDR", nargs="?", default=None,
                   const="rerun+http://127.0.0.1:9876/proxy", help="stream to a running Rerun viewer")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides")
    p.set_defaults(func=main, rerun_images_every=1, rerun_jpeg=None, rerun_mesh_every=0, overrides_anywhere=True)


def main(args) -> int:
    from slam.commands.run import viewer_observers
    from slam.config import load_config
    from slam.data.live import LiveFeed
    from slam.run.live import live_to_folder

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.max_frames is not None and args.max_frames < 1:
        raise SlamInputError(f"--max-frames must be at least 1, got {args.max_frames}")
    overrides = [*args.overrides, "data.realtime=true"]
    if args.device is not None:
        overrides.append(f"device={args.device}")
    cfg = load_config(args.config, overrides, profile=args.profile)
    out = Path(args.out)
    record = None if args.no_record else Path(args.record) if args.record else out / "frames"
    observers = viewer_observers(args)
    feed = LiveFeed(CAMERAS[args.camera](args), record=record, max_frames=args.max_frames)
    metrics = live_to_folder(cfg, feed, out, progress=not args.quiet, mesh=not args.no_mesh, observers=observers)
    rt = metrics["realtime"]
    print(json.dumps({"frames_received": metrics["frames_received"], **rt, "fpt_s": metrics["fpt_s"]}, default=str))
    again = f"; the frames received in {record} (lrslam run --data {record})" if record else ""
    print(f"outputs in {out}{again}")
    if metrics.get("camera_error"):
        print(f"lrslam live: the camera stopped early: {metrics['camera_error']}", file=sys.stderr)
    return 0
