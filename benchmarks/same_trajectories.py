"""Behaviour unchanged, by sha256: ``lrslam run --no-mesh data.max_frames=N`` on the synthetic room and both dev
sequences, in both loop modes, each in a fresh process; the hashes of ``trajectory.txt`` go to a JSON file.

A structural change is behaviour-preserving when its hashes equal the ones written before it, on the same
machine (floating-point results depend on the CPU's kernels, so hashes from another machine do not carry over)::

    python benchmarks/same_trajectories.py --out /tmp/before.json            # on the old tree
    python benchmarks/same_trajectories.py --out /tmp/after.json --against /tmp/before.json

or, against a worktree of the baseline in one session, whole sequences over seeds (the ATE of each run is kept, to
say by how much a change that is meant to change results did)::

    git worktree add /tmp/base 20b7b9c
    python benchmarks/same_trajectories.py --tree /tmp/base --preset tum/fr1_rpy-cpu-fast --modes preset \
        --seeds 5 --frames 0 --sequences tum_fr1_rpy tum_fr1_rpy_0_124 --out before.json
    python benchmarks/same_trajectories.py --preset tum/fr1_rpy-cpu-fast --modes preset --seeds 5 --frames 0 \
        --sequences tum_fr1_rpy tum_fr1_rpy_0_124 --out after.json --against before.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LRSLAM_SHARED_DATA", ROOT.parent / "shared" / "data"))

#: name -> (preset, data folder or None for the generated room)
SEQUENCES = {
    "synthetic": ("synthetic", None),
    "tum_fr1_rpy": ("tum/fr1_rpy-cpu", SHARED / "tum_fr1_rpy"),
    "tum_fr1_rpy_0_124": ("tum/fr1_rpy-cpu", SHARED / "tum_fr1_rpy_0_124"),
}


def run_one(preset: str, data: Path | None, parallel: bool | None, frames: int, out: Path, seed: int | None = None,
            tree: Path = ROOT, extra: list[str] = ()) -> tuple[str, float]:
    """``(sha256 of trajectory.txt, ATE RMSE in cm)`` of one ``lrslam run`` of the code in ``tree`` (``parallel``
    None: the preset's loop mode; ``frames`` 0: every frame; ``seed`` None: the preset's; ``extra``: more
    ``key=value`` overrides)."""
    cmd = [sys.executable, "-m", "slam", "run", "--config", preset, "--out", str(out), "--no-mesh", "--quiet",
           *extra]
    cmd += [f"data.max_frames={frames}"] if frames else []
    cmd += [] if parallel is None else [f"parallel={str(parallel).lower()}"]
    cmd += [] if seed is None else [f"seed={seed}"]
    if data is not None:
        cmd += ["--data", str(data)]
    subprocess.run(cmd, check=True, cwd=tree, env=dict(os.environ, PYTHONPATH=str(tree)))
    ate = json.loads((out / "metrics.json").read_text()).get("ate_rmse_m")
    return (hashlib.sha256((out / "trajectory.txt").read_bytes()).hexdigest(),
            None if ate is None else round(100 * ate, 4))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="JSON file for the hashes")
    ap.add_argument("--against", type=Path, help="an earlier JSON file: exit 1 unless every hash equals it")
    ap.add_argument("--frames", type=int, default=30, help="data.max_frames of each run (0: every frame)")
    ap.add_argument("--sequences", nargs="+", choices=sorted(SEQUENCES), default=list(SEQUENCES),
                    help="which sequences to run (default: all)")
    ap.add_argument("--preset", help="the preset of the TUM sequences instead of tum/fr1_rpy-cpu")
    ap.add_argument("--seeds", type=int, help="run seeds 0 ... N-1 of each case (default: the preset's seed)")
    ap.add_argument("--modes", nargs="+", choices=["serial", "parallel", "preset"], default=["serial", "parallel"],
                    help="loop modes (preset: the preset's own, for a preset whose mapper process needs parallel)")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                    help="overrides for every run (e.g. mapper_process=false, to compare two settings' hashes)")
    ap.add_argument("--tree", type=Path, default=ROOT,
                    help="the source tree whose code runs (a worktree of the baseline commit; default: this one)")
    args = ap.parse_args(argv)
    hashes, ates = {}, {}
    seeds = [None] if args.seeds is None else list(range(args.seeds))
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.sequences:
            preset, data = SEQUENCES[name]
            preset = args.preset if args.preset and data is not None else preset
            for mode in args.modes:
                for seed in seeds:
                    case = f"{name}/{mode}" + ("" if seed is None else f"/seed{seed}")
                    t0 = time.perf_counter()
                    parallel = None if mode == "preset" else mode == "parallel"
                    hashes[case], ates[case] = run_one(preset, data, parallel, args.frames, Path(tmp) / case, seed,
                                                       args.tree.resolve(), args.set)
                    print(f"{case:34s} {hashes[case][:16]}  ATE {ates[case]} cm  {time.perf_counter() - t0:5.1f} s",
                          flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"frames": args.frames, "preset": args.preset, "set": args.set, "tree": str(args.tree),
                                    "hashes": hashes, "ate_cm": ates}, indent=1) + "\n")
    if args.against is None:
        return 0
    before = json.loads(args.against.read_text())["hashes"]
    differ = [c for c in hashes if before.get(c) != hashes[c]]
    print("identical" if not differ else f"DIFFERENT: {', '.join(differ)}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
