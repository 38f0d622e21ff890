"""Replay a stretch of a run from its checkpoint under config variants, frame by frame against the ground truth.

Built for the whole walk's end-wall failure (docs/robustness.md, "Depth ICP holds what it cannot see"): the
camera turns about a metre in front of a wall and the estimate rolls about the wall's normal. The run is taken to
``--resume-at`` once (``lrslam run --stop-after``, kept in ``OUT/prefix``; about 25 minutes for the walk's frame
1960 on 2 cores), then every variant resumes from that checkpoint (the same map, poses and random state) and runs to
``--until``. Per frame: the estimate's position (cm) and orientation (degrees) error against the ground truth, the
orientation error as a world-frame rotation vector, and whether the frame was trusted. A variant is a list of
``key=value`` overrides; "" is the run's own config. The checkpoint's config check is skipped on purpose (a variant
changes what is computed), so only keys that need no other map (tracking's) make a fair replay.

Usage::

    python benchmarks/end_wall.py --config synthetic/walk --set representation=lrslam seed=2 data.max_frames=2100 \\
        --resume-at 1960 --until 2000 --variants "tracking.icp_hold=0" "tracking.icp_hold=3e-4" \\
        --out benchmarks/results/end_wall
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def errors(est: torch.Tensor, gt: torch.Tensor) -> dict:
    """Position (cm) and orientation (degrees) error of ``est`` against ``gt`` (``[4, 4]`` camera-to-world), and the
    orientation error as a world-frame rotation vector (degrees)."""
    from slam.core.pose import rotation_vector

    est, gt = est.double(), gt.double()
    vec = rotation_vector(est[:3, :3] @ gt[:3, :3].T)
    return {"cm": 100 * float((est[:3, 3] - gt[:3, 3]).norm()), "deg": math.degrees(float(vec.norm())),
            "world_rotvec_deg": [round(math.degrees(float(v)), 3) for v in vec]}


def replay(cfg, checkpoint: Path, until: int) -> list[dict]:
    """Resume a fresh system under ``cfg`` from ``checkpoint`` and run it to frame position ``until``."""
    from slam.core.pose import pose_to_matrix
    from slam.engine.setup import load_data, resolve_device
    from slam.engine.system import SLAM
    from slam.run.checkpoint import load_run, restore

    system = SLAM(cfg, load_data(cfg), resolve_device(cfg.device))
    rows = []
    try:
        start = restore(system, load_run(checkpoint))
        for k in range(start, min(until, len(system.indices))):
            system.step(k)
            row = {"k": k, "trusted": bool(system.state.trusted[-1])}
            if system.gt is not None:
                row.update(errors(pose_to_matrix(system.state.est[k]), system.gt[k]))
            rows.append(row)
    finally:
        system.close()
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="synthetic/walk")
    ap.add_argument("--set", nargs="*", default=[], help="overrides of the run itself (key=value)")
    ap.add_argument("--resume-at", type=int, required=True, help="frame position the replays start from")
    ap.add_argument("--until", type=int, required=True, help="frame position the replays stop before")
    ap.add_argument("--variants", nargs="+", default=[""], help='each a space-separated list of key=value ("": none)')
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    if not 0 < args.resume_at < args.until:
        ap.error("--resume-at must be positive and below --until")

    from _stamp import stamp
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, run_to_folder

    prefix = args.out / "prefix"
    if not (prefix / "checkpoint.pt").exists():
        try:
            run_to_folder(load_config(args.config, args.set), prefix, mesh=False, stop_after=args.resume_at)
        except RunInterrupted:
            pass  # stopped where asked: the checkpoint is the start of every replay
    result = {"stamp": stamp(), "config": args.config, "set": args.set, "resume_at": args.resume_at,
              "until": args.until, "variants": {}}
    for variant in args.variants:
        cfg = load_config(args.config, [*args.set, *variant.split()])
        rows = replay(cfg, prefix / "checkpoint.pt", args.until)
        worst = max((r["deg"] for r in rows if "deg" in r), default=float("nan"))
        result["variants"][variant or "(the run's config)"] = {"frames": rows, "max_deg": worst}
        print(f"{variant or '(the run config)'}: largest orientation error {worst:.2f} deg over frames "
              f"{args.resume_at}-{args.until - 1}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "end_wall.json").write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
