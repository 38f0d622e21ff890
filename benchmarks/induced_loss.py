"""Relocalisation on an induced loss: a TUM sequence with a run of frames blacked out (depth zeroed, colour black),
over seeds: frames lost, recovered and relocalised, and the ATE before, across and after the gap.

The modified copy links every file of the source except the blacked-out frames, whose colour and depth are written
as valid all-zero PNGs of the same size (a sensor that saw nothing: the loader reads them, the loop finds no depth).
Each run is ``lrslam run`` (through :func:`slam.run.runner.run_to_folder`); ATE is aligned once on the whole trajectory,
then its RMSE is split into the frames before the gap and those after it. Writes ``induced_loss.json`` (every seed's
values, mean ± std) and prints a table.

Usage::

    python benchmarks/induced_loss.py --data ../shared/data/tum_fr1_rpy --gap 40:55 --seeds 5 \\
        --out benchmarks/results/induced_loss
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def blacked_out_copy(src: Path, dst: Path, first: int, stop: int, frames=None, depth_only: bool = False) -> list[str]:
    """``src`` (a TUM folder with associations.txt) linked into ``dst`` with the associated pairs
    ``first..stop-1`` (or the positions ``frames``) replaced by all-zero colour and depth PNGs (with
    ``depth_only``, depth only: the colour is kept). Returns the replaced file names."""
    import imageio.v3 as iio

    pairs = [ln.split() for ln in (src / "associations.txt").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]
    frames = range(first, stop) if frames is None else frames
    black = {pairs[i][3] for i in frames} | (set() if depth_only else {pairs[i][1] for i in frames})
    dst.mkdir(parents=True)
    for name in os.listdir(src):
        if name not in ("rgb", "depth"):
            os.symlink((src / name).resolve(), dst / name)
    for sub in ("rgb", "depth"):
        (dst / sub).mkdir()
        for name in os.listdir(src / sub):
            rel = f"{sub}/{name}"
            if rel in black:
                img = iio.imread(src / rel)
                iio.imwrite(dst / rel, np.zeros_like(img))
            else:
                os.symlink((src / rel).resolve(), dst / rel)
    return sorted(black)


def split_ate(traj: Path, gt: Path, first: int, stop: int) -> dict:
    """ATE RMSE (cm) of the frames before the gap, after it, in it and of all of them, under one rigid alignment
    fitted on the frames outside the gap (the gap's poses are predictions of frames nobody saw; fitting on them
    would spread their error over the rest)."""
    from slam.eval import ate, read_tum_trajectory

    _, est = read_tum_trajectory(traj)
    _, ref = read_tum_trajectory(gt)
    outside = np.ones(len(est), bool)
    outside[first:stop] = False
    T = ate(est[outside], ref[outside]).transform
    err = np.linalg.norm(est[:, :3, 3] @ T[:3, :3].T + T[:3, 3] - ref[:, :3, 3], axis=1)

    def rmse(e):
        return round(100 * float(np.sqrt(np.mean(e**2))), 3)

    return {"ate_cm": rmse(err), "ate_before_cm": rmse(err[:first]), "ate_after_cm": rmse(err[stop:]),
            "ate_gap_cm": rmse(err[first:stop])}


def run_seed(preset: str, data: Path, out: Path, seed: int, first: int, stop: int, extra: list[str]) -> dict:
    from slam.config import load_config
    from slam.run.runner import run_to_folder

    cfg = load_config(preset, [f"data.path={data}", f"seed={seed}", *extra])
    t0 = time.perf_counter()
    m = run_to_folder(cfg, out, progress=False, mesh=False)
    ev = m["events"]
    rec = {"seed": seed, "wall_s": round(time.perf_counter() - t0, 1), "frames_lost": m["frames_lost"],
           "frames_recovered": m["frames_recovered"],
           "frames_relocalised": sum(1 for e in ev if e.get("relocalised")),
           "frames_without_depth": sum(1 for e in ev if "no valid depth" in e["event"]),
           "relocalised_at": [e["frame"] for e in ev if e.get("relocalised")],
           "first_trusted_after_gap": _first_trusted_after(out, stop)}
    rec.update(split_ate(out / "trajectory.txt", out / "trajectory_gt.txt", first, stop))
    return rec


def _first_trusted_after(out: Path, stop: int) -> int | None:
    import csv

    with open(out / "frames.csv") as fh:
        for row in csv.DictReader(fh):
            if int(row["k"]) >= stop and row["trusted"] == "1":
                return int(row["k"])
    return None


def _summary(runs: list[dict], key: str) -> str:
    vals = [r[key] for r in runs]
    return f"{statistics.mean(vals):.2f} ± {statistics.stdev(vals):.2f}" if len(vals) > 1 else f"{vals[0]:.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "tum_fr1_rpy"))
    ap.add_argument("--config", default="tum/fr1_rpy-cpu")
    ap.add_argument("--gap", default="40:55", help="blacked-out frames A:B (pairs A..B-1 of associations.txt)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", default="benchmarks/results/induced_loss")
    ap.add_argument("overrides", nargs="*", help="config overrides for every run (e.g. tracking.relocalize_after=0)")
    args = ap.parse_args(argv)
    first, stop = map(int, args.gap.split(":"))
    out = Path(args.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)  # run folders and the data copy (git ignores runs/)
    data = out / "runs" / f"{Path(args.data).name}"  # the folder name tells the TUM loader the camera (fr1)
    if not data.exists():
        blacked_out_copy(Path(args.data), data, first, stop)
    runs = []
    for seed in range(args.seeds):
        runs.append(run_seed(args.config, data, out / "runs" / f"s{seed}", seed, first, stop, args.overrides))
        print(json.dumps(runs[-1]), flush=True)
    import tdfields
    from slam.engine.runtime import cpu_name

    doc = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "version": tdfields.__version__,
           "cpu": cpu_name(), "config": args.config, "data": args.data, "gap": [first, stop],
           "overrides": args.overrides, "runs": runs,
           "mean_std": {k: _summary(runs, k) for k in ("ate_cm", "ate_before_cm", "ate_after_cm", "frames_lost",
                                                     "frames_relocalised")}}
    (out / "induced_loss.json").write_text(json.dumps(doc, indent=2))
    print("\n| metric | mean ± std over seeds |\n|---|---|")
    for k, v in doc["mean_std"].items():
        print(f"| {k} | {v} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
