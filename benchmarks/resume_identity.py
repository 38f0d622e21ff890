"""Interrupted = uninterrupted, byte for byte: for every sequence, seed and loop mode, one run straight through and
one stopped by a real SIGINT after frame ``--at`` (a mapping call still pending in parallel mode) and resumed.

Each pair must give the same ``trajectory.txt`` (sha256). The uninterrupted runs are also the accuracy runs of the
current code: ``slam_compare.json`` holds them in :mod:`benchmarks.slam_compare`'s format, so
``lrslam compare benchmarks/results/accuracy_kernel8 OUT`` tests them against the published 5-seed runs.

Usage::

    python benchmarks/resume_identity.py --seeds 5 --at 50 --out benchmarks/results/resume_identity
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = Path(os.environ.get("LRSLAM_SHARED_DATA", ROOT.parent / "shared" / "data"))


def sigint_at(k: int):
    """An observer sending SIGINT to this process after frame ``k`` (the run's own handler stops after it)."""
    from slam.engine.observers import Observer

    class SigintAt(Observer):
        def on_frame(self, run, rec):
            if rec.k == k:
                os.kill(os.getpid(), signal.SIGINT)

    return SigintAt()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def pair(preset: str, data: Path, seed: int, parallel: bool, at: int, out: Path) -> dict:
    """One uninterrupted run and one interrupted after frame ``at`` then resumed; their hashes and metrics."""
    from slam.run.checkpoint import load_run
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, run_to_folder

    cfg = load_config(preset, [f"data.path={data}", f"seed={seed}", f"parallel={str(parallel).lower()}"])
    tag = f"{data.name}-s{seed}-{'par' if parallel else 'seq'}"
    full, cut = out / f"{tag}-full", out / f"{tag}-resumed"
    t0 = time.perf_counter()
    m = run_to_folder(cfg, full, progress=False, mesh=False)
    t_full = time.perf_counter() - t0
    try:
        run_to_folder(cfg, cut, progress=False, mesh=False, observers=[sigint_at(at)])
        raise SystemExit(f"{tag}: the SIGINT after frame {at} did not stop the run")
    except RunInterrupted:
        pass
    pending = [p["k"] for p in load_run(cut / "checkpoint.pt")["extra"]["run"]["pending"]]
    m2 = run_to_folder(cfg, cut, progress=False, mesh=False, resume=True)
    a, b = _sha(full / "trajectory.txt"), _sha(cut / "trajectory.txt")
    return {"sequence": preset, "data": str(data), "representation": cfg.representation, "backend": "auto",
            "seed": seed, "repeat": 0, "parallel": parallel, "interrupted_after": at, "pending_at_stop": pending,
            "resumed_from": m2["resumed_from"], "sha256_uninterrupted": a, "sha256_resumed": b, "identical": a == b,
            "num_frames": m["num_frames"], "ate_rmse_cm": round(100 * m["ate_rmse_m"], 4),
            "ate_mean_cm": round(100 * m["ate_mean_m"], 4), "accuracy_cm": None, "completion_cm": None,
            "completion_ratio_pct": None, "depth_l1_cm": None, "fpt_s": round(m["fpt_s"], 4),
            "events": len(m["events"]), "frames_lost": m["frames_lost"], "wall_s": round(t_full, 1),
            **{k: m["parameters"][k] for k in ("geometry", "appearance", "decoders", "total")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="tum/fr1_rpy-cpu")
    ap.add_argument("--data", nargs="+", default=[str(SHARED / "tum_fr1_rpy"), str(SHARED / "tum_fr1_rpy_0_124")])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--modes", nargs="+", default=["parallel", "sequential"], choices=["parallel", "sequential"])
    ap.add_argument("--at", type=int, default=50, help="interrupt after this frame position")
    ap.add_argument("--out", default="benchmarks/results/resume_identity")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    import tdfields
    from slam.engine.runtime import cpu_name

    runs = []
    for mode in args.modes:
        for data in map(Path, args.data):
            for seed in range(args.seeds):
                runs.append(pair(args.config, data, seed, mode == "parallel", args.at, out / "runs"))
                r = runs[-1]
                print(f"{data.name} seed {seed} {mode}: identical={r['identical']} pending={r['pending_at_stop']} "
                      f"ATE {r['ate_rmse_cm']:.3f} cm", flush=True)
                doc = {"stamp": {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                                 "version": tdfields.__version__, "cpu": cpu_name(), "threads": 1},
                       "command": " ".join(sys.argv),
                       "runs": [r for r in runs if r["parallel"]],  # the default mode: the accuracy runs
                       "sequential_runs": [r for r in runs if not r["parallel"]],
                       "all_identical": all(r["identical"] for r in runs), "failed": []}
                (out / "slam_compare.json").write_text(json.dumps(doc, indent=2))
    print(f"all identical: {all(r['identical'] for r in runs)} ({len(runs)} pairs)")
    return 0 if all(r["identical"] for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
