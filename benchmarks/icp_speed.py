"""Depth ICP as numba kernels against the tensor-op reference (issue 21; docs/benchmarks.md,
"Depth ICP as kernels").

For every consecutive pair of frames of each sequence, one thread, ``icp_relative_pose`` runs with
``kernel=True`` and ``kernel=False`` in turn (the kernels compiled or loaded before timing); per sequence: the
median time of a registration each way, and how many registrations agree: the same float32 pose and verdict,
inlier share and RMS within 1e-12 (the kernels sum the normal equations in another order, so the float64
pose may differ in its last bits; ``max_pose_diff`` is the largest float32 pose difference seen).

    python benchmarks/icp_speed.py --data ../shared/data/tum_fr1_rpy_0_124 ../shared/data/tum_fr1_rpy \\
        --out benchmarks/results/icp_speed_registration.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def measure(path: Path) -> dict:
    import torch

    from slam.core.odometry import icp_relative_pose
    from slam.data import load_dataset

    ds = load_dataset(path)
    depths = [torch.as_tensor(ds[i].depth, dtype=torch.float32) for i in range(len(ds))]
    icp_relative_pose(depths[0], depths[1], ds.intrinsics)  # numba compiles or loads its cache here, untimed
    times = {"kernel": [], "reference": []}
    same, max_diff = 0, 0.0
    for i in range(len(depths) - 1):
        res = {}
        for name in (("kernel", "reference") if i % 2 == 0 else ("reference", "kernel")):
            t0 = time.perf_counter()
            res[name] = icp_relative_pose(depths[i], depths[i + 1], ds.intrinsics, kernel=name == "kernel")
            times[name].append(time.perf_counter() - t0)
        a, b = res["kernel"], res["reference"]
        max_diff = max(max_diff, float((a.relative - b.relative).abs().max()))
        close = abs(a.inliers - b.inliers) <= 1e-12 and (a.rmse_m == b.rmse_m or abs(a.rmse_m - b.rmse_m) <= 1e-12)
        same += torch.equal(a.relative, b.relative) and a.ok == b.ok and close
    med = {k: statistics.median(v) for k, v in times.items()}
    return {"sequence": str(path), "registrations": len(depths) - 1, "identical": same, "max_pose_diff": max_diff,
            "median_ms": {k: 1000 * v for k, v in med.items()}, "ratio": med["kernel"] / med["reference"],
            "times_s": times}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", nargs="+", type=Path, required=True, help="sequence folders")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    import torch

    from _stamp import stamp

    torch.set_num_threads(1)
    results = []
    for path in args.data:
        r = measure(path)
        results.append(r)
        print(f"{path.name}: kernel {r['median_ms']['kernel']:.1f} ms, reference {r['median_ms']['reference']:.1f} ms "
              f"({r['ratio']:.2f}x), {r['identical']}/{r['registrations']} identical", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"stamp": stamp(), "command": " ".join(sys.argv), "results": results}, indent=1)
                        + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
