"""``lrslam run``: track and map a sequence, write trajectory, mesh, checkpoint and metrics; ``--resume`` goes on
from a run folder's checkpoint."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

from slam.errors import SlamInputError

# the turn between taken frames (95th percentile) past which a run is told its frames were far apart: the fast
# fr1_rpy window every 4th frame (90th percentile 12.6 degrees) lost the tracker before tracking.icp_wide
FAR_APART_DEG = 10.0


def _profiles_help() -> str:
    from slam.config.profiles import PROFILES, describe

    width = max(map(len, PROFILES))
    return "\n".join(f"  {name:<{width}}  {describe(name)}" for name in PROFILES)


def _epilog() -> str:
    return (
        "profiles (--profile; the budget, apart from the data; measured in docs/profiles.md):\n"
        + _profiles_help() + "\n"
        "presets (--config; the data: camera, crop, a published box): synthetic, synthetic/walk, tum,\n"
        "         tum/fr1_rpy, tum/fr1_desk, 7scenes, replica, replica/room0, scannet, scannet/scene0000, bag\n"
        "overrides are dotted key=value pairs, e.g. tracking.iters=20 representation=eslam bound=auto\n"
        "resume an interrupted run:  lrslam run --resume runs/rpy   (only device, mapper_process,\n"
        "         preload_kernels, data.max_bad_fraction, data.prefetch, data.prefetch_in, checkpoint_every,\n"
        "         checkpoint_interval_s and mapping.keyframe_spill_dir may be changed on resume)"
    )


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="run SLAM on a sequence (default: the bundled synthetic room on the CPU)",
        description=(
            "Run LRSLAM (or ESLAM / an ablation via representation=...) on a sequence. With no arguments it "
            "tracks and maps the bundled synthetic room on the CPU; --data DIR alone runs any dataset folder or "
            "bag: its kind is detected, the camera read from it, the box sized from its first frames, at the "
            "device's default profile (realtime on the CPU, paper on CUDA). Outputs in --out: trajectory.txt, "
            "trajectory_gt.txt, mesh.ply, trajectory.png, config.yaml, checkpoint.pt, metrics.json. "
            "A checkpoint is written every minute (checkpoint_every / checkpoint_interval_s); Ctrl-C or SIGTERM "
            "finish the current frame, write the outputs so far (metrics.json marked partial) and say how to "
            "go on with --resume (the resumed run gives the uninterrupted run's trajectory, byte for byte); a "
            "second Ctrl-C stops at once."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=_epilog(),
    )
    p.add_argument("--config", default=None, help="preset name or YAML file (default: the preset of the --data "
                                                  "folder's detected kind; without --data: synthetic)")
    p.add_argument("--profile", default=None, help="realtime, quality, paper or a YAML file (default: realtime on the "
                                                   "CPU, paper with --device cuda)")
    p.add_argument("--data", default=None, help="dataset folder, ROS 1 .bag file or ROS 2 bag folder (default: the "
                                                "preset's; synthetic: bundled)")
    p.add_argument("--out", default=None, help="output folder (default: runs/<preset>-<representation>)")
    p.add_argument("--device", default=None, choices=["cpu", "cuda"], help="torch device (default: the config's; with --resume, the kind the run computed on)")
    p.add_argument("--resume", metavar="OUT_DIR", default=None,
                   help="go on from the latest checkpoint of this run folder (same config and data)")
    p.add_argument("--stop-after", metavar="N", type=int, default=None,
                   help="stop like Ctrl-C once N frames are done (outputs so far, a checkpoint; exit 0): split a "
                        "long run into time-boxed jobs with --resume")
    p.add_argument("--realtime", action="store_true",
                   help="replay the data at their recorded rate as a live camera delivers them (data.realtime=true): "
                        "the newest frame that has arrived is processed next and the ones it passed are dropped; "
                        "metrics.json's 'realtime' holds frames processed and dropped and the latency from a "
                        "frame's arrival to its pose; the trajectory holds the processed frames")
    p.add_argument("--no-mesh", action="store_true", help="skip mesh extraction and reconstruction metrics")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    v = p.add_argument_group("Rerun viewer (needs rerun-sdk: the viewer extra)")
    v.add_argument("--rerun", metavar="FILE.rrd", default=None,
                   help="log the run (frames, trajectories, camera, live ATE, mesh) to a Rerun recording")
    v.add_argument("--rerun-connect", metavar="ADDR", nargs="?", default=None,
                   const="rerun+http://127.0.0.1:9876/proxy",
                   help="stream to a running Rerun viewer (default address: rerun+http://127.0.0.1:9876/proxy)")
    v.add_argument("--rerun-images-every", metavar="N", type=int, default=1,
                   help="log the colour and depth frames every N frames (default 1)")
    v.add_argument("--rerun-jpeg", metavar="Q", type=int, default=None,
                   help="JPEG-compress the logged colour frames at quality Q (default: raw)")
    v.add_argument("--rerun-mesh-every", metavar="N", type=int, default=0,
                   help="also log an unculled preview mesh every N keyframes (default 0: the final mesh only)")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides")
    p.set_defaults(func=main, overrides_anywhere=True)


def main(args) -> int:
    from slam.config import load_config
    from slam.config.load import flatten, parse_overrides
    from slam.engine.setup import check_spill_dir
    from slam.run.outputs import finished_metrics
    from slam.run.runner import RunInterrupted, resume_config, run_to_folder

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.resume is not None:
        given = [flag for flag, v in (("--config", args.config), ("--profile", args.profile), ("--data", args.data),
                                      ("--out", args.out), ("--realtime", args.realtime)) if v]
        if given:
            raise SlamInputError(f"--resume continues a run with its own config and data; drop {', '.join(given)}")
        out = Path(args.resume)
        over = flatten(parse_overrides(args.overrides))
        if args.device is not None:
            over["device"] = args.device
        cfg = resume_config(out, over)
        if finished_metrics(out) is not None:
            print(f"{out}: this run is complete; nothing to resume")
            return 0
    else:
        overrides = list(args.overrides)
        if args.data is not None:
            overrides.append(f"data.path={args.data}")
        if args.device is not None:
            overrides.append(f"device={args.device}")
        if args.realtime:
            overrides.append("data.realtime=true")
        preset = args.config or (data_preset(args.data) if args.data is not None else "synthetic")
        cfg = load_config(preset, overrides, profile=args.profile)
        if args.config is None and args.data is not None and not args.quiet:
            print(f"lrslam run: {args.data}: {preset} data, profile {cfg.profile} (choose with --config, --profile)",
                  file=sys.stderr)
        check_spill_dir(cfg)
        out = Path(args.out) if args.out else Path("runs") / f"{cfg.name.replace('/', '_')}-{cfg.representation}"
    if args.stop_after is not None and args.stop_after < 1:
        raise SlamInputError(f"--stop-after must be at least 1 frame, got {args.stop_after}")
    observers = viewer_observers(args)
    t0 = time.perf_counter()
    try:
        metrics = run_to_folder(cfg, out, progress=not args.quiet, mesh=not args.no_mesh,
                                resume=args.resume is not None, observers=observers, stop_after=args.stop_after)
    except RunInterrupted as exc:
        print(f"lrslam run: {exc}", file=sys.stderr)
        return exc.exit_code
    _print_summary(metrics, out, time.perf_counter() - t0)
    for obs in observers:
        share = 100 * obs.log_s / metrics["loop_s"] if metrics.get("loop_s") else float("nan")
        where = f"recording in {args.rerun} (view it with: rerun {args.rerun})" if args.rerun else "streamed"
        print(f"Rerun {where}; logging took {obs.log_s:.2f} s in this process ({share:.1f} % of the loop)")
    return 0


def _print_summary(metrics: dict, out: Path, wall_s: float) -> None:
    """The run's one-line JSON summary and where its outputs are; a line on stderr when its frames were far apart."""
    summary = {k: metrics.get(k) for k in ("num_frames", "ate_rmse_m", "ate_mean_m", "fpt_s")}
    summary["parameters_total"] = metrics["parameters"]["total"]
    if "reconstruction" in metrics:
        summary["reconstruction"] = metrics["reconstruction"]
    summary["wall_s"] = round(wall_s, 1)
    print(json.dumps(summary, indent=None, default=str))
    print(f"outputs in {out}")
    turn = (metrics.get("frame_steps") or {}).get("turn_deg")
    if turn and turn["p95"] > FAR_APART_DEG:  # a low frame rate, or a real-time run on a CPU too slow for it
        print(f"lrslam run: the frames taken were far apart (turn between them: median {turn['median']:.1f}, 95th "
              f"percentile {turn['p95']:.1f} degrees); beyond about {FAR_APART_DEG:g} degrees the trajectory's error "
              "grows (docs/robustness.md, \"How far apart the frames can be\")", file=sys.stderr)


def data_preset(path: str) -> str:
    """The bundled preset for the data at ``path``: the one named after the dataset kind its layout is detected as
    (``tum``, ``7scenes``, ``replica``, ``scannet``, ``bag``).

    Raises:
        SlamInputError: ``path`` is missing or no dataset's layout (the message lists the layouts)."""
    from slam.config.presets import CONFIG_DIR
    from slam.data import detect_layout

    kind = detect_layout(Path(path).expanduser())
    if not (CONFIG_DIR / f"{kind}.yaml").is_file():  # every probed kind has one: tests/slam/commands check it
        raise SlamInputError(f"{path}: {kind} data has no preset; name one with --config")
    return kind


def viewer_observers(args) -> list:
    """The Rerun observer the flags ask for (checked before the run starts), or none."""
    if args.rerun is None and args.rerun_connect is None:
        return []
    from slam.run.viewer import RerunObserver, check_recording_path, require_rerun

    require_rerun()
    save = check_recording_path(args.rerun) if args.rerun is not None else None
    return [RerunObserver(save=save, connect=args.rerun_connect, images_every=args.rerun_images_every,
                          jpeg_quality=args.rerun_jpeg, mesh_every=args.rerun_mesh_every)]
