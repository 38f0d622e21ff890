"""Tracking from known offsets on the synthetic room: how many Levenberg-Marquardt evaluations
(``tracking.optimizer: gauss_newton``) and how many Adam iterations (ESLAM's tracker) bring the camera within
1 mm and 0.1 degree of where the tracker settles, and what each costs.

The room is mapped over its first ``--frames`` frames (sequential mode, the synthetic preset). For each later test
frame and offset, the start is the ground-truth pose moved by ``offset`` cm and degrees along the diagonal of every
axis; "settled" is Levenberg-Marquardt run to 60 evaluations with tight step tolerances (the optimum of the map's
loss, which differs from the ground truth by the map's own error). Both trackers use the preset's pixels and
samples. Times are medians over the calls, both trackers interleaved in one process.

Usage::

    python benchmarks/gn_convergence.py --out benchmarks/results/gn_convergence
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
GN_BUDGETS = (2, 3, 4, 5, 6, 8, 10, 12, 16)
ADAM_BUDGETS = (5, 10, 20, 40, 80)


def _first_within(distances: dict, mm: float = 1.0, deg: float = 0.1):
    """The smallest budget whose pose is within ``mm`` and ``deg`` of the settled one (None: none is)."""
    return next((n for n, (d, r) in distances.items() if d * 1000 <= mm and r <= deg), None)


def measure(frames: int, test_frames: list[int], offsets: list[float], extra: list[str], device: str = "cpu") -> dict:
    from slam.config import load_config
    from slam.core.pose import exp_se3, matrix_to_pose
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.engine.tracker import track_frame
    from slam.engine.tracking_guard import motion

    cfg = load_config("synthetic", [f"data.max_frames={max(test_frames) + 1}", "parallel=false", *extra])
    s = SLAM(cfg, load_data(cfg), device)
    for k in range(frames):
        s.step(k)
    s.finish()
    gn = copy.deepcopy(cfg)
    gn.tracking.optimizer = "gauss_newton"
    tight = copy.deepcopy(gn)
    tight.tracking.gn_step_m, tight.tracking.gn_step_deg = 1e-7, 1e-6
    cases, t_gn, t_adam = [], [], []
    for k in test_frames:
        frame = s.frames.get(k)
        for off in offsets:
            xi = torch.tensor([math.radians(off) / math.sqrt(3)] * 3 + [off / 100 / math.sqrt(3)] * 3)
            start = matrix_to_pose(exp_se3(xi) @ s.gt[k])

            def run(c, iters):
                t0 = time.perf_counter()
                r = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(k),
                                iters=iters)
                return r, time.perf_counter() - t0

            settled, _ = run(tight, 60)
            row = {"frame": k, "offset_cm_deg": off, "start_to_settled": motion(settled.pose, start),
                   "settled_to_gt": motion(settled.pose, matrix_to_pose(s.gt[k])), "gn": {}, "adam": {}}
            for n in GN_BUDGETS:
                r, dt = run(tight, n)
                t_gn.append(dt / max(r.iters, 1))
                row["gn"][n] = motion(settled.pose, r.pose)
            for n in ADAM_BUDGETS:
                r, dt = run(cfg, n)
                t_adam.append(dt / max(r.iters, 1))
                row["adam"][n] = motion(settled.pose, r.pose)
            row["gn_evals_to_1mm_0.1deg"] = _first_within(row["gn"])
            row["adam_iters_to_1mm_0.1deg"] = _first_within(row["adam"])
            cases.append(row)
            print(f"frame {k} offset {off} cm/deg: GN {row['gn_evals_to_1mm_0.1deg']} evaluations, "
                  f"Adam {row['adam_iters_to_1mm_0.1deg']} iterations", flush=True)
    s.close()
    return {"cases": cases, "gn_s_per_evaluation": statistics.median(t_gn),
            "adam_s_per_iteration": statistics.median(t_adam), "frames_mapped": frames,
            "pixels": cfg.tracking.pixels, "samples": cfg.rendering.n_stratified + cfg.rendering.n_importance,
            "device": str(device)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=12, help="frames mapped before the test frames")
    ap.add_argument("--test-frames", type=int, nargs="+", default=[12, 16])
    ap.add_argument("--offsets", type=float, nargs="+", default=[1.0, 3.0, 5.0], help="cm and degrees")
    ap.add_argument("--device", default="cpu", help="torch device of the scene and frames (cuda: the GPU check)")
    ap.add_argument("overrides", nargs="*", help="config key=value for the synthetic preset")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _stamp import stamp

    res = measure(args.frames, args.test_frames, args.offsets, args.overrides, args.device)
    res.update(stamp(args.device))  # the device measured on, not the stamp's default
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "gn_convergence.json").write_text(json.dumps(res, indent=1, default=str) + "\n")
    print(f"per evaluation: GN {res['gn_s_per_evaluation'] * 1000:.1f} ms, Adam {res['adam_s_per_iteration'] * 1000:.1f} ms"
          f" per iteration; written {args.out / 'gn_convergence.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
