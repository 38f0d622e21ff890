"""Behaviour unchanged, by sha256: ``lrslam run --no-mesh data.max_frames=N`` on the synthetic room and both dev
sequences, in both loop modes, each in a fresh process; the hashes of ``trajectory.txt`` go to a JSON file.

A structural change is behaviour-preserving when its hashes equal the ones written before it, on the same
machine (floating-point results depend on the CPU's kernels, so hashes from another machine do not carry over)::

    python benchmarks/same_trajectories.py --out /tmp/before.json            # on the old tree
    python benchmarks/same_trajectories.py --out /tmp/after.json --against /tmp/before.json
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


def run_one(preset: str, data: Path | None, parallel: bool, frames: int, out: Path) -> str:
    cmd = [sys.executable, "-m", "slam", "run", "--config", preset, "--out", str(out), "--no-mesh", "--quiet",
           f"data.max_frames={frames}", f"parallel={str(parallel).lower()}"]
    if data is not None:
        cmd += ["--data", str(data)]
    subprocess.run(cmd, check=True, cwd=ROOT)
    return hashlib.sha256((out / "trajectory.txt").read_bytes()).hexdigest()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="JSON file for the hashes")
    ap.add_argument("--against", type=Path, help="an earlier JSON file: exit 1 unless every hash equals it")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--sequences", nargs="+", choices=sorted(SEQUENCES), default=list(SEQUENCES),
                    help="which sequences to run (default: all)")
    args = ap.parse_args(argv)
    hashes = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.sequences:
            preset, data = SEQUENCES[name]
            for parallel in (False, True):
                case = f"{name}/{'parallel' if parallel else 'serial'}"
                t0 = time.perf_counter()
                hashes[case] = run_one(preset, data, parallel, args.frames, Path(tmp) / case)
                print(f"{case:34s} {hashes[case][:16]}  {time.perf_counter() - t0:5.1f} s", flush=True)
    args.out.write_text(json.dumps({"frames": args.frames, "hashes": hashes}, indent=1) + "\n")
    if args.against is None:
        return 0
    before = json.loads(args.against.read_text())["hashes"]
    differ = [c for c in hashes if before.get(c) != hashes[c]]
    print("identical" if not differ else f"DIFFERENT: {', '.join(differ)}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
