"""``lrslam synth``: write the synthetic room sequence to a folder."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(subparsers) -> None:
    from slam.data.synthetic import SynthConfig

    d = SynthConfig()
    p = subparsers.add_parser(
        "synth",
        help="generate the synthetic RGB-D room sequence (Replica layout)",
        description=(
            "Render the procedural room along a hand-held-like loop into colour, depth, exact poses and a "
            "ground-truth mesh, written in the Replica layout (results/, traj.txt, mesh.ply, cam.json)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: the cache folder used by `lrslam run`)")
    p.add_argument("--frames", type=int, default=d.frames)
    p.add_argument("--height", type=int, default=d.height)
    p.add_argument("--width", type=int, default=d.width)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--depth-noise", type=float, default=d.depth_noise_sigma, metavar="SIGMA",
                   help="Gaussian depth noise std in metres")
    p.add_argument("--sensor-holes", action="store_true", help="Kinect-like depth noise and holes")
    p.add_argument("--color-noise", type=float, default=d.color_noise_sigma, metavar="SIGMA")
    p.add_argument("--loop-frames", type=int, default=d.loop_frames, help="frames per loop around the room")
    p.add_argument("--supersample", type=int, default=d.supersample, help="colour anti-aliasing rays per axis")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from slam.data.synthetic import SynthConfig, default_sequence, generate

    cfg = SynthConfig(
        seed=args.seed, frames=args.frames, height=args.height, width=args.width,
        depth_noise_sigma=args.depth_noise, sensor_holes=args.sensor_holes, color_noise_sigma=args.color_noise,
        loop_frames=args.loop_frames, supersample=args.supersample,
    )
    t0 = time.perf_counter()
    out = default_sequence(cfg=cfg) if args.out is None else generate(args.out, cfg)
    k = cfg.intrinsics()
    print(f"wrote {cfg.frames} frames {k.height}x{k.width} (fx={k.fx:g}) to {out} in {time.perf_counter() - t0:.1f} s")
    return 0
