"""``lrslam eval``: ATE of a trajectory and reconstruction metrics of a mesh, as a table and JSON."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "eval",
        help="trajectory error (ATE) and mesh metrics against ground truth",
        description=(
            "ATE between two TUM-format trajectories (timestamp tx ty tz qx qy qz qw), poses paired by "
            "timestamp, rigidly aligned (Horn/Umeyama) unless --align says otherwise; and/or accuracy, "
            "completion, completion ratio and Depth L1 of a reconstructed mesh against a ground-truth mesh. "
            "All numbers are metres (the table also shows cm)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--trajectory", type=Path, help="estimated trajectory (TUM format)")
    p.add_argument("--gt", type=Path, help="ground-truth trajectory (TUM format)")
    p.add_argument("--align", choices=("rigid", "sim3", "none"), default="rigid")
    p.add_argument("--max-dt", type=float, default=0.02, help="timestamp pairing tolerance (s)")
    p.add_argument("--plot", type=Path, help="write a top-down trajectory plot (PNG)")
    p.add_argument("--mesh", type=Path, help="reconstructed mesh")
    p.add_argument("--gt-mesh", type=Path, help="ground-truth mesh")
    p.add_argument("--samples", type=int, default=200_000, help="surface samples per mesh")
    p.add_argument("--threshold", type=float, default=0.05, help="completion-ratio distance (m)")
    p.add_argument("--icp", action="store_true", help="ICP-align the mesh to the ground truth first")
    p.add_argument("--depth-views", type=int, default=100, help="virtual views for Depth L1 (0 = skip; reference 1000)")
    p.add_argument("--depth-box", type=float, nargs=6, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="box (m) for the Depth L1 camera centres (default: the reference rule from the GT box; "
                        "the synthetic room uses -1.2 -1.2 0.9 1.2 1.2 2.0)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, help="write the numbers to this JSON file")
    p.set_defaults(func=main)


def main(args) -> int:
    from slam.errors import SlamInputError

    if args.trajectory is None and args.mesh is None:
        raise SlamInputError("nothing to evaluate: give --trajectory/--gt and/or --mesh/--gt-mesh")
    if (args.trajectory is None) != (args.gt is None):
        raise SlamInputError("--trajectory and --gt go together")
    if (args.mesh is None) != (args.gt_mesh is None):
        raise SlamInputError("--mesh and --gt-mesh go together")
    out: dict = {}
    rows: list[tuple[str, str]] = []
    if args.trajectory is not None:
        from slam.eval.ate import ate_from_files

        res, _ = ate_from_files(args.trajectory, args.gt, align=args.align, max_dt=args.max_dt)
        out.update(res.as_dict())
        rows += [("frames paired", f"{res.n}"), ("alignment", args.align)]
        if args.align == "sim3":
            rows.append(("scale", f"{res.scale:.4f}"))
        for key in ("rmse", "mean", "median", "std", "min", "max"):
            v = getattr(res, key)
            rows.append((f"ATE {key}", f"{v * 100:8.3f} cm  ({v:.6f} m)"))
        if args.plot is not None:
            from slam.eval.plots import plot_trajectory

            plot_trajectory(res.aligned, res.gt, args.plot, align="none",
                            title=f"{args.trajectory.name}: ATE RMSE {res.rmse * 100:.2f} cm ({args.align})")
            rows.append(("plot", str(args.plot)))
    if args.mesh is not None:
        import numpy as np

        from slam.eval.mesh_metrics import align_mesh, depth_l1, load_mesh, reconstruction_metrics

        rec = load_mesh(args.mesh, "reconstructed mesh")
        gt = load_mesh(args.gt_mesh, "ground-truth mesh")
        if args.icp:  # one alignment for both metrics
            rec, transform = align_mesh(rec, gt, seed=args.seed)
            out["icp_translation_m"] = float(np.linalg.norm(transform[:3, 3]))
        m = reconstruction_metrics(rec, gt, samples=args.samples, threshold=args.threshold, seed=args.seed)
        out.update({k: m[k] for k in ("accuracy_m", "completion_m", "completion_ratio")})
        rows += [
            ("accuracy", f"{m['accuracy_m'] * 100:8.3f} cm"),
            ("completion", f"{m['completion_m'] * 100:8.3f} cm"),
            (f"completion ratio (<{args.threshold * 100:g} cm)", f"{m['completion_ratio'] * 100:8.2f} %"),
        ]
        if args.depth_views > 0:
            box = (args.depth_box[:3], args.depth_box[3:]) if args.depth_box else None
            d = depth_l1(rec, gt, views=args.depth_views, seed=args.seed, camera_box=box)
            out["depth_l1_m"] = d
            rows.append((f"Depth L1 ({args.depth_views} views)", f"{d * 100:8.3f} cm"))
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0
