"""``lrslam synth``: write a synthetic sequence (the room or the walk) to a folder."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(subparsers) -> None:
    from slam.data.synthetic import SCENES, WALK_FRAMES, SynthConfig

    d = SynthConfig()
    p = subparsers.add_parser(
        "synth",
        help="generate a synthetic RGB-D sequence, the room or the walk (Replica layout)",
        description=(
            "Render a procedural scene along a hand-held-like path into colour, depth, exact poses and a "
            "ground-truth mesh, written in the Replica layout (results/, traj.txt, mesh.ply, cam.json). "
            "--scene room: a 4 m room circled by the camera (120 frames by default). --scene walk: three "
            "connected rooms along 20 m, walked through and back at 0.57 m/s (2100 frames by default) with "
            "Kinect-like depth (--sensor-holes on, --supersample 1, --loop-frames 2100 unless given)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: the cache folder used by `lrslam run`)")
    p.add_argument("--scene", choices=SCENES, default="room", help="which scene to render")
    p.add_argument("--frames", type=int, default=argparse.SUPPRESS,
                   help=f"frames (default: {d.frames}, the walk {WALK_FRAMES})")
    p.add_argument("--height", type=int, default=d.height)
    p.add_argument("--width", type=int, default=d.width)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--depth-noise", type=float, default=d.depth_noise_sigma, metavar="SIGMA",
                   help="Gaussian depth noise std in metres")
    p.add_argument("--sensor-holes", action="store_true", default=argparse.SUPPRESS,
                   help="Kinect-like depth noise and holes (always on for the walk)")
    p.add_argument("--color-noise", type=float, default=d.color_noise_sigma, metavar="SIGMA")
    p.add_argument("--loop-frames", type=int, default=argparse.SUPPRESS,
                   help=f"frames per loop around the room or along the walk (default: {d.loop_frames}, the walk "
                        f"{WALK_FRAMES})")
    p.add_argument("--supersample", type=int, default=argparse.SUPPRESS,
                   help=f"colour anti-aliasing rays per axis (default: {d.supersample}, the walk 1)")
    p.set_defaults(func=main)


def main(args) -> int:
    from slam.data.synthetic import SynthConfig, default_sequence, generate, walk_config

    given = {k: getattr(args, k) for k in ("frames", "sensor_holes", "loop_frames", "supersample") if hasattr(args, k)}
    opts = dict(seed=args.seed, height=args.height, width=args.width, depth_noise_sigma=args.depth_noise,
                color_noise_sigma=args.color_noise, **given)
    cfg = walk_config(**opts) if args.scene == "walk" else SynthConfig(**opts)
    t0 = time.perf_counter()
    out = default_sequence(cfg=cfg) if args.out is None else generate(args.out, cfg)
    k = cfg.intrinsics()
    print(f"wrote {cfg.frames} frames {k.height}x{k.width} (fx={k.fx:g}) to {out} in {time.perf_counter() - t0:.1f} s")
    return 0
