"""Interrupted = uninterrupted, byte for byte: for every sequence, seed and loop mode, one run straight through and
one stopped after frame ``--at`` and resumed. ``--fault`` chooses the stop: ``sigint`` (default: a real SIGINT
in this process after that frame, a mapping call still pending in parallel mode), or, for a preset with the mapper
in its own process (``mapper_process: true``), a run of ``lrslam run`` in a session of its own given ``sigterm-group``
(SIGTERM to its whole process group, as Slurm's scancel or a systemd stop send it: the run checkpoints, exit 143)
or ``kill-child`` (SIGKILL to its mapping process, as the out-of-memory killer does: the run stops in one line,
exit 1, and resumes from its last checkpoint) once its checkpoint (written every 10 frames) has passed ``--at``.

Each pair must give the same ``trajectory.txt`` (sha256). The uninterrupted runs are also the accuracy runs of the
current code: ``slam_compare.json`` holds them in :mod:`benchmarks.slam_compare`'s format, so
``lrslam compare benchmarks/results/accuracy_kernel8 OUT`` tests them against the published 5-seed runs.

Usage::

    python benchmarks/resume_identity.py --seeds 5 --at 50 --out benchmarks/results/resume_identity
    python benchmarks/resume_identity.py --config tum/fr1_rpy-cpu-fast --modes parallel --fault kill-child \
        --out benchmarks/results/mapper_faults/kill-child
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


def _mapping_child(pid: int) -> int:
    """The pid of run ``pid``'s mapping process (not multiprocessing's resource tracker); Linux's /proc."""
    for kid in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        if "spawn_main" in Path(f"/proc/{kid}/cmdline").read_text():
            return int(kid)
    raise SystemExit(f"run {pid} has no mapping process: --fault kill-child needs mapper_process: true")


def faulted(preset: str, overrides: list[str], at: int, fault: str, cut: Path) -> str:
    """``lrslam run`` in a session of its own, stopped by ``fault`` once its checkpoint has passed frame ``at``;
    returns the one line it ended with."""
    import subprocess

    from slam.run.checkpoint import load_run

    cmd = [sys.executable, "-m", "slam.cli", "run", "--quiet", "--no-mesh", "--config", preset, "--out", str(cut),
           *overrides, "checkpoint_every=10"]  # a key a resume may change: it decides when to write, not what
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    while True:
        if proc.poll() is not None:
            raise SystemExit(f"{cut.name}: the run ended before frame {at}: {proc.stderr.read()[-1000:]}")
        try:
            if load_run(cut / "checkpoint.pt")["extra"]["run"]["next"] >= at:
                break
        except Exception:  # noqa: BLE001 - not written yet, or being replaced
            pass
        time.sleep(0.1)
    if fault == "sigterm-group":
        os.killpg(proc.pid, signal.SIGTERM)
    else:
        os.kill(_mapping_child(proc.pid), signal.SIGKILL)
    _, err = proc.communicate()
    want = 143 if fault == "sigterm-group" else 1
    lines = [ln for ln in err.splitlines() if ln.startswith("lrslam run:")]
    if proc.returncode != want or len(lines) != 1 or "Traceback" in err:
        raise SystemExit(f"{cut.name}: {fault} ended with exit {proc.returncode}, not {want} and one line:\n"
                         f"{err[-2000:]}")
    return lines[0]


def pair(preset: str, data: Path, seed: int, parallel: bool, at: int, out: Path, fault: str = "sigint",
         extra: list[str] = ()) -> dict:
    """One uninterrupted run and one stopped by ``fault`` after frame ``at`` then resumed; their hashes and
    metrics."""
    from slam.run.checkpoint import load_run
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, run_to_folder

    overrides = [f"data.path={data}", f"seed={seed}", f"parallel={str(parallel).lower()}", *extra]
    cfg = load_config(preset, overrides)
    tag = f"{data.name}-s{seed}-{'par' if parallel else 'seq'}"
    full, cut = out / f"{tag}-full", out / f"{tag}-resumed"
    t0 = time.perf_counter()
    m = run_to_folder(cfg, full, progress=False, mesh=False)
    t_full = time.perf_counter() - t0
    said = None
    if fault == "sigint":
        try:
            run_to_folder(cfg, cut, progress=False, mesh=False, observers=[sigint_at(at)])
            raise SystemExit(f"{tag}: the SIGINT after frame {at} did not stop the run")
        except RunInterrupted:
            pass
    else:
        said = faulted(preset, overrides, at, fault, cut)
    stopped = load_run(cut / "checkpoint.pt")["extra"]["run"]
    pending = [p["k"] for p in stopped["pending"]]
    m2 = run_to_folder(cfg, cut, progress=False, mesh=False, resume=True)
    a, b = _sha(full / "trajectory.txt"), _sha(cut / "trajectory.txt")
    return {"sequence": preset, "data": str(data), "representation": cfg.representation, "backend": "auto",
            "seed": seed, "repeat": 0, "parallel": parallel, "fault": fault, "interrupted_after": at,
            "checkpoint_next": stopped["next"], "said": said, "pending_at_stop": pending,
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
    ap.add_argument("--fault", default="sigint", choices=["sigint", "sigterm-group", "kill-child"],
                    help="how the run is stopped (see above; the last two need mapper_process: true)")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="config overrides of every run")
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
                runs.append(pair(args.config, data, seed, mode == "parallel", args.at, out / "runs", args.fault,
                                 args.set))
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
