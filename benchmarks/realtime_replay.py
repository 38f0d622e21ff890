"""Real time as a camera delivers it: ``lrslam run --realtime`` on each sequence and seed, one run at a time in a
fresh process (nothing else should run on the machine: a real-time run's frames depend on its speed). Each run's
frames processed and dropped, latency from arrival to pose and ATE over the processed frames go to a JSON file,
with the per-seed values and a summary per sequence (mean ± std over seeds), stamped with date, version and CPU.

Usage::

    python benchmarks/realtime_replay.py --seeds 5 --out benchmarks/results/realtime_replay/default.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LRSLAM_SHARED_DATA", ROOT.parent / "shared" / "data"))


def run_one(preset: str, data: Path | None, seed: int, out: Path, extra: list[str] = ()) -> dict:
    """One real-time run; its ``realtime`` block, ATE (cm), frame time and start-up (s)."""
    cmd = [sys.executable, "-m", "slam", "run", "--config", preset, "--out", str(out), "--no-mesh", "--quiet",
           "--realtime", f"seed={seed}", *extra]
    if data is not None:
        cmd += ["--data", str(data)]
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    m = json.loads((out / "metrics.json").read_text())
    ate = m.get("ate_rmse_m")
    return {"seed": seed, **m["realtime"], "ate_rmse_cm": None if ate is None else round(100 * ate, 4),
            "fpt_s": round(m["fpt_s"], 4), "preload_s": round(m["preload_s"], 3), "frames_lost": m["frames_lost"],
            "mapping_calls": m["mapping_calls"], "mapping_declined": m.get("mapping_declined"),
            "mapping_wait_s": round(m["mapping_wait_s"], 3), "frames_odometry": m.get("frames_odometry"),
            # ICP starts taken from wider starts (tracking.icp_wide): frames the tracker took too far apart
            "wide_starts": sum(1 for e in m["events"] if e.get("wide_start"))}


def summary(runs: list[dict]) -> dict:
    """Mean ± std over seeds of each number."""
    out = {}
    for key in ("frames_processed", "frames_dropped", "latency_median_s", "latency_p95_s", "ate_rmse_cm", "fpt_s",
                "mapping_calls", "mapping_declined"):
        vals = np.asarray([r[key] for r in runs if r.get(key) is not None], dtype=float)
        if vals.size:
            out[key] = {"mean": round(float(vals.mean()), 4), "std": round(float(vals.std(ddof=1)), 4)
                        if vals.size > 1 else 0.0}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="tum", help="preset (default tum: what lrslam run --data gives a TUM folder)")
    ap.add_argument("--data", nargs="+", default=[str(SHARED / "tum_fr1_rpy"), str(SHARED / "tum_fr1_rpy_0_124")],
                    help="data folders ('bundled': the preset's own data)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="overrides for every run")
    ap.add_argument("--out", type=Path, required=True, help="JSON file")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _stamp import stamp

    doc = {"stamp": stamp(), "command": " ".join(sys.argv), "config": args.config, "set": args.set, "sequences": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for data in args.data:
            folder = None if data == "bundled" else Path(data)
            name = "bundled" if folder is None else folder.name
            runs = []
            for seed in range(args.seeds):
                runs.append(run_one(args.config, folder, seed, Path(tmp) / f"{name}-s{seed}", args.set))
                r = runs[-1]
                print(f"{name} seed {seed}: {r['frames_processed']} processed, {r['frames_dropped']} dropped, "
                      f"latency {r.get('latency_median_s')} s (p95 {r.get('latency_p95_s')}), ATE {r['ate_rmse_cm']} cm",
                      flush=True)
            doc["sequences"][name] = {"runs": runs, "summary": summary(runs)}
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
