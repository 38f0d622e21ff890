"""Side-by-side SLAM comparison: lrslam vs eslam vs CP/CP (and other representations) on the same sequences.

Runs ``slam.runner.run_to_folder`` for every (sequence, representation) pair with identical settings and writes
``slam_compare.json``, ``slam_compare.csv`` and ``slam_compare.md`` (ATE, reconstruction, FPT, parameters),
stamped with date, library version, CPU and thread count. Parameter counts come from ``tdfields.report`` via
each run's ``metrics.json``.

Usage::

    python benchmarks/slam_compare.py --out benchmarks/results                       # synthetic + TUM excerpt
    python benchmarks/slam_compare.py --sequences synthetic --representations lrslam eslam
    python benchmarks/slam_compare.py --sequences tum/fr1_rpy-cpu=../shared/data/tum_fr1_rpy
    python benchmarks/slam_compare.py --sequences synthetic --backends auto torch --out benchmarks/results/fused

``--backends`` repeats every run with each tdfields kernel backend (``auto``: the fused kernels; ``torch``: the
pure-PyTorch reference), for a before/after table of the fused kernels on the same sequence and settings.

``--repeats N`` runs every configuration N times, interleaved (A, B, A, B, ...) so slow phases of a shared machine
hit every configuration alike; ``fpt_s`` is then the median and ``fpt_runs_s`` lists the runs. Meshing and mesh
metrics run on the first repeat only (the runs are deterministic for a seed; only their timing varies).
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DEFAULT_SEQUENCES = ["synthetic", f"tum/fr1_rpy-cpu={ROOT.parent / 'shared' / 'data' / 'tum_fr1_rpy'}"]
COLUMNS = ["sequence", "representation", "backend", "num_frames", "ate_rmse_cm", "ate_mean_cm", "accuracy_cm", "completion_cm",
           "completion_ratio_pct", "depth_l1_cm", "fpt_s", "fpt_runs_s", "geometry", "appearance", "decoders", "total"]


def _cm(v):
    return None if v is None else round(100 * v, 3)


def row_of(seq: str, rep: str, m: dict, backend: str = "auto") -> dict:
    rec = m.get("reconstruction") or {}
    p = m["parameters"]
    return {
        "sequence": seq, "representation": rep, "backend": backend, "num_frames": m["num_frames"],
        "ate_rmse_cm": _cm(m.get("ate_rmse_m")), "ate_mean_cm": _cm(m.get("ate_mean_m")),
        "accuracy_cm": _cm(rec.get("accuracy_m")), "completion_cm": _cm(rec.get("completion_m")),
        "completion_ratio_pct": None if rec.get("completion_ratio") is None else round(100 * rec["completion_ratio"], 2),
        "depth_l1_cm": _cm(rec.get("depth_l1_m")), "fpt_s": round(m["fpt_s"], 3), "fpt_runs_s": None,
        "geometry": p["geometry"], "appearance": p["appearance"], "decoders": p["decoders"], "total": p["total"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", nargs="+", default=DEFAULT_SEQUENCES,
                    help="PRESET or PRESET=DATA_PATH (default: synthetic and the TUM fr1_rpy excerpt, CPU variant)")
    ap.add_argument("--representations", nargs="+", default=["lrslam", "eslam", "cp_cp"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--no-mesh", action="store_true")
    ap.add_argument("--backends", nargs="+", default=["auto"], choices=["auto", "torch", "numba"],
                    help="tdfields kernel backends to run each configuration with (default: auto)")
    ap.add_argument("--repeats", type=int, default=1,
                    help="runs per configuration, interleaved; FPT is their median (default 1)")
    ap.add_argument("overrides", nargs="*", metavar="key=value", help="applied to every run")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")

    import tdfields
    from slam.config import load_config
    from tdfields import kernels
    from slam.runner import run_to_folder
    from slam.runtime import cpu_name

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for seq in args.sequences:
        preset, _, data = seq.partition("=")
        if data and not Path(data).exists():
            print(f"skip {preset}: data not found at {data}", file=sys.stderr)
            continue
        first: dict[tuple[str, str], dict] = {}
        fpts: dict[tuple[str, str], list[float]] = {}
        for repeat in range(args.repeats):
            for backend in args.backends:
                kernels.set_backend(backend)
                for rep in args.representations:
                    over = [f"representation={rep}", *args.overrides] + ([f"data.path={data}"] if data else [])
                    cfg = load_config(preset, over)
                    suffix = ("" if backend == "auto" else f"-{backend}") + (f"-r{repeat}" if repeat else "")
                    run_dir = out / "runs" / f"{preset.replace('/', '_')}-{rep}{suffix}"
                    t0 = time.perf_counter()
                    m = run_to_folder(cfg, run_dir, progress=True, mesh=not args.no_mesh and repeat == 0)
                    print(f"{preset} {rep} [{backend}] run {repeat + 1}/{args.repeats}: ATE {m.get('ate_rmse_m')} m, "
                          f"FPT {m['fpt_s']:.3f} s, {time.perf_counter() - t0:.0f} s wall", file=sys.stderr)
                    first.setdefault((backend, rep), m)
                    fpts.setdefault((backend, rep), []).append(m["fpt_s"])
            kernels.set_backend("auto")
        for backend in args.backends:
            for rep in args.representations:
                row = row_of(preset, rep, first[(backend, rep)], backend)
                if args.repeats > 1:
                    row["fpt_s"] = round(statistics.median(fpts[(backend, rep)]), 3)
                    row["fpt_runs_s"] = " / ".join(f"{v:.3f}" for v in fpts[(backend, rep)])
                rows.append(row)
    import torch

    stamp = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "version": tdfields.__version__,
             "cpu": cpu_name(), "threads": torch.get_num_threads(), "torch": torch.__version__}
    (out / "slam_compare.json").write_text(json.dumps({"stamp": stamp, "rows": rows}, indent=2))
    with open(out / "slam_compare.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    lines = [f"# SLAM comparison ({stamp['date']}, tdfields {stamp['version']}, {stamp['cpu']}, "
             f"{stamp['threads']} thread(s), torch {stamp['torch']})", "",
             "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join("-" if r[c] is None else (f"{r[c]:,}" if isinstance(r[c], int) and c in
                                       ("geometry", "appearance", "decoders", "total") else str(r[c]))
                                       for c in COLUMNS) + " |")
    (out / "slam_compare.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
