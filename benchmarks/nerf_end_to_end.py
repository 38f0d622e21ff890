"""End to end against nerfstudio's TensoRF (issue 23): ``ns-train`` then ``ns-eval`` per variant, each a fresh
process, one at a time, in rounds (every variant once per round, so a slow stretch of a shared machine hits all of
them), at docs/nerf.md's settings: the synthetic room (24 views of 48x64, 3 held out), 400 steps of 1,024 rays,
64 uniform + 32 importance samples a ray, 32 -> 64 samples per axis at steps 100 and 200, one thread.

With ``--seeds``, every variant runs once per seed (``--machine.seed``; nerfstudio's default is 42) in each round.
Per run: the whole ``ns-train`` process's wall time (importing nerfstudio and setting up included), the median
training iteration (nerfstudio's ``Train Iter (time)`` from its tensorboard log) and ``ns-eval``'s held-out PSNR and
SSIM. Writes ``OUT/summary.json``: every run, and per variant the medians of wall and step time, the mean and
standard deviation of PSNR and SSIM over its runs, and the ratios to the first variant's.

Needs the environment of ``.ci/nerfstudio_job.sh VENV``::

    python benchmarks/nerf_end_to_end.py --venv /tmp/nsvenv --out benchmarks/results/nerf_deferred \\
        --variant "tensorf-no-lpips=tensorf-no-lpips" \\
        --variant "hybrid=tdfields-hybrid" \\
        --variant "hybrid, deferred=tdfields-hybrid --pipeline.model.colour-head deferred"

A variant is ``LABEL=METHOD [ns-train model options ...]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

SETTINGS = ["--vis", "tensorboard", "--machine.device-type", "cpu", "--max-num-iterations", "400",
            "--pipeline.datamanager.train-num-rays-per-batch", "1024", "--pipeline.model.init-resolution", "32",
            "--pipeline.model.final-resolution", "64", "--pipeline.model.upsampling-iters", "100", "200",
            "--pipeline.model.num-uniform-samples", "64", "--pipeline.model.num-samples", "32"]
ENV = {"OMP_NUM_THREADS": "1", "TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD": "1",
       "NERFSTUDIO_METHOD_CONFIGS": "tensorf-no-lpips=tdfields.integrations.nerfstudio_methods:tensorf_no_lpips"}


_READ_ITERATIONS = """
import statistics, sys
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
events = EventAccumulator(sys.argv[1], size_guidance={"scalars": 0})
events.Reload()
print(statistics.median(e.value for e in events.Scalars("Train Iter (time)")))
"""


def iteration_seconds(venv: Path, run_dir: Path) -> float:
    """Median of nerfstudio's ``Train Iter (time)`` scalars in the run's tensorboard log (read with the venv's
    tensorboard, which the project's environment need not have)."""
    out = subprocess.run([str(venv / "bin" / "python"), "-c", _READ_ITERATIONS, str(run_dir)], check=True,
                         capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def run_one(venv: Path, room: Path, out: Path, label: str, method: str, options: list[str], tag: str,
            seed: int) -> dict:
    env = {**os.environ, **ENV}
    options = [*options, "--machine.seed", str(seed)]
    log = out / f"{tag}.log"
    cmd = [str(venv / "bin" / "ns-train"), method, *SETTINGS, *options, "--output-dir", str(out / "runs"),
           "--timestamp", tag, "nerfstudio-data", "--data", str(room), "--center-method", "none",
           "--auto-scale-poses", "False"]
    t0 = time.perf_counter()
    with open(log, "w") as f:
        subprocess.run(cmd, env=env, stdout=f, stderr=subprocess.STDOUT, check=True)
    wall = time.perf_counter() - t0
    run_dir = out / "runs" / "unnamed" / method / tag
    metrics = out / f"{tag}_eval.json"
    with open(out / f"{tag}_eval.log", "w") as f:
        subprocess.run([str(venv / "bin" / "ns-eval"), "--load-config", str(run_dir / "config.yml"),
                        "--output-path", str(metrics)], env=env, stdout=f, stderr=subprocess.STDOUT, check=True)
    results = json.loads(metrics.read_text())["results"]
    return {"variant": label, "method": method, "options": options, "seed": seed, "wall_s": wall,
            "step_s": iteration_seconds(venv, run_dir), "psnr": results["psnr"], "ssim": results["ssim"]}


def summarise(runs: list[dict], labels: list[str]) -> list[dict]:
    rows = []
    for label in labels:
        mine = [r for r in runs if r["variant"] == label]
        if not mine:  # a variant whose first run is still to come
            continue
        row = {"variant": label, "runs": len(mine), "seeds": sorted({r["seed"] for r in mine}),
               **{k: statistics.median(r[k] for r in mine) for k in ("wall_s", "step_s")}}
        for k in ("psnr", "ssim"):
            values = [r[k] for r in mine]
            row[k] = statistics.mean(values)
            row[f"{k}_std"] = statistics.stdev(values) if len(values) > 1 else 0.0
        rows.append(row)
    for row in rows:
        row["wall_ratio"] = row["wall_s"] / rows[0]["wall_s"]
        row["step_ratio"] = row["step_s"] / rows[0]["step_s"]
        row["psnr_difference"] = row["psnr"] - rows[0]["psnr"]
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--venv", required=True, type=Path, help="the environment .ci/nerfstudio_job.sh VENV built")
    ap.add_argument("--variant", action="append", required=True, help="LABEL=METHOD [options]; the first is the "
                    "reference of the ratios")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--seeds", type=int, nargs="+", default=[42], help="nerfstudio seeds (default: its 42)")
    ap.add_argument("--room", type=Path, default=Path("/tmp/nerf_end_to_end_room"),
                    help="nerfstudio dataset folder (the synthetic room, written if absent)")
    ap.add_argument("--out", required=True, type=Path)
    args = ap.parse_args(argv)
    if not (args.venv / "bin" / "ns-train").is_file():
        ap.error(f"--venv {args.venv}: no bin/ns-train there (build it with bash .ci/nerfstudio_job.sh {args.venv})")

    from _nerf_room import ensure_room
    from _stamp import stamp

    ensure_room(args.room)
    args.out.mkdir(parents=True, exist_ok=True)
    variants = []
    for text in args.variant:
        label, _, command = text.partition("=")
        if not command:
            ap.error(f"--variant {text!r}: expected LABEL=METHOD [options]")
        method, *options = shlex.split(command)
        variants.append((label, method, options))
    runs = []
    for r in range(args.rounds):
        for seed in args.seeds:
            for i, (label, method, options) in enumerate(variants):
                runs.append(run_one(args.venv, args.room, args.out, label, method, options, f"r{r}_s{seed}_v{i}",
                                    seed))
                print(json.dumps(runs[-1]), flush=True)
                summary = {"stamp": {**stamp(), "torch_threads": 1}, "settings": " ".join(SETTINGS),
                           "runs": runs, "variants": summarise(runs, [v[0] for v in variants])}
                (args.out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    for row in summary["variants"]:
        print(f"{row['variant']:<40} wall {row['wall_s']:7.1f} s ({row['wall_ratio']:.2f}x)  step "
              f"{row['step_s']:.3f} s ({row['step_ratio']:.2f}x)  PSNR {row['psnr']:.2f} ± {row['psnr_std']:.2f} "
              f"({row['psnr_difference']:+.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
