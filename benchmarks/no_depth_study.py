"""Frames without depth, tracked on colour or predicted: TUM sequences with the depth of some frames zeroed (their
colour kept), ``tracking.without_depth`` ``color`` against ``predict``, over seeds, interleaved.

A frame without depth is never mapped; with ``color`` its rotation is tracked on its colour against the map's
rendered depth (slam/engine/tracker.py, ``track_on_color``), with ``predict`` it keeps the motion model's pose.
For every dropped frame the study measures the error of its motion since the last frame before it that had depth
(estimated relative pose against the ground truth's: translation in cm, rotation in degrees; this is what tracking
a frame decides, free of the drift before it), and the run's ATE. Each run is ``lrslam run``
(:func:`slam.run.runner.run_to_folder`). Writes ``no_depth_study.json`` (every seed's values, mean ± std per
sequence and mode) and prints a table.

Usage::

    python benchmarks/no_depth_study.py --seeds 5 --out benchmarks/results/no_depth
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

SHARED = ROOT.parent / "shared" / "data"
MODES = ("predict", "color")


def parse_frames(text: str) -> list[int]:
    """``"15,25,60:63"`` -> ``[15, 25, 60, 61, 62]``."""
    out = []
    for part in text.split(","):
        a, _, b = part.partition(":")
        out += list(range(int(a), int(b))) if b else [int(a)]
    return sorted(set(out))


def gap_errors(traj: Path, gt: Path, drop: list[int]) -> dict:
    """Per dropped frame, the error of its motion since the last earlier frame not dropped (cm, degrees), and the
    ATE RMSE (cm) of all frames and of the dropped ones (one alignment on the others)."""
    from slam.eval import ate, read_tum_trajectory

    _, est = read_tum_trajectory(traj)
    _, ref = read_tum_trajectory(gt)
    cm, deg = [], []
    for k in drop:
        j = max(i for i in range(k) if i not in drop)
        d = np.linalg.inv(np.linalg.inv(ref[j]) @ ref[k]) @ (np.linalg.inv(est[j]) @ est[k])
        cm.append(100 * float(np.linalg.norm(d[:3, 3])))
        deg.append(float(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))))
    kept = np.ones(len(est), bool)
    kept[drop] = False
    T = ate(est[kept], ref[kept]).transform
    err = np.linalg.norm(est[:, :3, 3] @ T[:3, :3].T + T[:3, 3] - ref[:, :3, 3], axis=1)
    return {"gap_motion_cm": float(np.mean(cm)), "gap_motion_deg": float(np.mean(deg)), "per_frame_cm": cm,
            "per_frame_deg": deg, "ate_cm": 100 * float(np.sqrt(np.mean(err**2))),
            "ate_dropped_cm": 100 * float(np.sqrt(np.mean(err[drop] ** 2)))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", nargs="+", default=[str(SHARED / "tum_fr1_rpy"), str(SHARED / "tum_fr1_rpy_0_124")])
    ap.add_argument("--config", default="tum/fr1_rpy-cpu")
    ap.add_argument("--drop", default="15,25,35,45,60:63,75,85,95", help="frames whose depth is zeroed (A:B ranges)")
    ap.add_argument("--frames", type=int, default=100, help="frames of each sequence")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", default="benchmarks/results/no_depth")
    args = ap.parse_args(argv)
    from induced_loss import blacked_out_copy
    from slam.config import load_config
    from slam.engine.runtime import cpu_name, float_fingerprint
    from slam.run.runner import run_to_folder

    drop = parse_frames(args.drop)
    out = Path(args.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)  # git ignores runs/
    runs = []
    for src in map(Path, args.data):
        data = out / "runs" / src.name / src.name  # the folder name tells the TUM loader the camera (fr1)
        if not data.exists():
            blacked_out_copy(src, data, 0, 0, frames=drop, depth_only=True)
        for seed in range(args.seeds):
            for mode in MODES:  # interleaved: both modes of a seed see the machine in the same state
                folder = out / "runs" / src.name / f"{mode}_s{seed}"
                cfg = load_config(args.config, [f"data.path={data}", f"seed={seed}", f"data.max_frames={args.frames}",
                                                f"tracking.without_depth={mode}"])
                t0 = time.perf_counter()
                m = run_to_folder(cfg, folder, progress=False, mesh=False)
                rec = {"sequence": src.name, "mode": mode, "seed": seed, "wall_s": round(time.perf_counter() - t0, 1),
                       "color_tracked": sum(1 for e in m["events"] if e.get("color_tracked")),
                       "frames_lost": m["frames_lost"]}
                rec.update(gap_errors(folder / "trajectory.txt", folder / "trajectory_gt.txt", drop))
                runs.append(rec)
                print(json.dumps({k: v for k, v in rec.items() if not k.startswith("per_frame")}), flush=True)
    summary = []
    for seq in dict.fromkeys(r["sequence"] for r in runs):
        for mode in MODES:
            rs = [r for r in runs if r["sequence"] == seq and r["mode"] == mode]
            row = {"sequence": seq, "mode": mode, "seeds": len(rs)}
            for key in ("gap_motion_cm", "gap_motion_deg", "ate_dropped_cm", "ate_cm"):
                vals = [r[key] for r in rs]
                row[key] = {"mean": statistics.fmean(vals), "std": statistics.stdev(vals) if len(vals) > 1 else None}
            summary.append(row)
    import tdfields

    doc = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "version": tdfields.__version__,
           "cpu": cpu_name(), "float_fingerprint": float_fingerprint(), "config": args.config, "drop": drop,
           "frames": args.frames, "runs": runs, "summary": summary}
    (out / "no_depth_study.json").write_text(json.dumps(doc, indent=1))

    def pm(s):
        return f"{s['mean']:.2f}" + ("" if s["std"] is None else f" ± {s['std']:.2f}")

    print("\n| sequence | without_depth | seeds | dropped frames' motion error cm | deg | ATE of dropped frames cm "
          "| ATE cm |\n|---|---|---|---|---|---|---|")
    for r in summary:
        print(f"| {r['sequence']} | {r['mode']} | {r['seeds']} | {pm(r['gap_motion_cm'])} | {pm(r['gap_motion_deg'])} "
              f"| {pm(r['ate_dropped_cm'])} | {pm(r['ate_cm'])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
