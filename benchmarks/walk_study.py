"""The long walk (issue 24): lrslam and eslam on the synthetic walk (``--config synthetic/walk``: three connected
rooms along a 20 m building) over seeds, with the map growing as the camera walks, against the fixed box from the
first frames.

For every (representation, seed) it runs ``lrslam run`` (``slam.run.runner.run_to_folder``) on the first
``--frames`` frames and keeps ATE, the mesh's accuracy and completion against the walk's ground-truth mesh, frame
time, growths and the final parameters and field bytes. For seed 0 of each it reads ``frames.csv`` (parameters
and bytes after every frame) and the ground-truth trajectory to give parameters and bytes against the distance
walked. The baseline is lrslam with ``scene.grow=false`` (the box from the first frames, seed 0): its completion
ratio is how much of the walked building a fixed box maps.

Usage::

    python benchmarks/walk_study.py --frames 1050 --seeds 5 --out /tmp/walk1050
    python benchmarks/walk_study.py --frames 2100 --seeds 5 --continue --out benchmarks/results/walk_full
        # the whole walk, spread over sittings: each runs what is missing and may be stopped at any time;
        # --from-partial then summarises the seeds every config has finished

Writes ``walk_study.json`` (every run's values per seed, the summaries, the per-frame series), ``walk_study.png``
(parameters and bytes against metres walked); docs/results.md is then rewritten by ``python benchmarks/results_page.py``.

``--loop-oracle`` runs nothing: it re-solves the pose graph of each run with loops that OUT/walk_study.json lists,
with each accepted loop's relative pose taken from the ground truth, and writes ``loop_oracle.json``: the ATE of the
tracker, of the measured loops' correction (the run's own) and of exact loops'. If exact loops leave the ATE where
it was, better loop measurement cannot help: the error is one the loops do not observe.

``--refine-study ITERS`` runs only the end of each run with loops (written without the global refinement): its
checkpoint is resumed with ``loops.refine_iters=ITERS`` into OUT/refine/, once on the corrected poses and once, the
control, on the tracker's, and ``refine.json`` gives the mesh's accuracy, completion and depth L1 of both beside the
run's own.
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
sys.path.insert(0, str(Path(__file__).resolve().parent))

CONFIGS = {"lrslam": ["representation=lrslam"], "eslam": ["representation=eslam"],
           "lrslam, fixed box": ["representation=lrslam", "scene.grow=false"],
           "lrslam, loops": ["representation=lrslam", "loops.enabled=true"]}


def run(name: str, seed: int, frames: int, mesh_resolution: float, out: Path) -> dict:
    from slam.config import load_config
    from slam.run.runner import run_to_folder

    folder = out / "runs" / f"{name.replace(', ', '_').replace(' ', '_')}_s{seed}"
    cfg = load_config("synthetic/walk", [*CONFIGS[name], f"seed={seed}", f"data.max_frames={frames}",
                                         f"meshing.resolution={mesh_resolution}"])
    t0 = time.perf_counter()
    m = run_to_folder(cfg, folder, progress=True)
    rec = m.get("reconstruction") or {}
    cm = (lambda v: None if v is None else 100 * v)
    return {"config": name, "seed": seed, "frames": frames, "folder": str(folder.relative_to(out)),
            "wall_s": time.perf_counter() - t0,
            "ate_rmse_cm": cm(m.get("ate_rmse_m")), "accuracy_cm": cm(rec.get("accuracy_m")),
            # loop closure: ATE above is the corrected trajectory's, this the tracker's own
            "ate_odometry_cm": cm(m.get("ate_odometry_rmse_m")), "loops": (m.get("loops") or {}).get("loops"),
            "loop_candidates": (m.get("loops") or {}).get("candidates_tried"),
            "completion_cm": cm(rec.get("completion_m")),
            "completion_ratio_pct": None if rec.get("completion_ratio") is None else 100 * rec["completion_ratio"],
            "fpt_s": m["fpt_s"], "growths": sum(str(e.get("event", "")).startswith("scene box grown")
                                                for e in m.get("events", [])),
            "events": len(m.get("events", [])), "parameters": m["parameters"]["total"],
            "float_fingerprint": m.get("float_fingerprint")}  # seeds spread over sittings may span machines


def series(out: Path, folder: str) -> list[dict]:
    """``[{frame, metres, parameters, field_bytes}]`` of one run: metres walked along the ground truth."""
    import numpy as np

    gt = np.loadtxt(out / folder / "trajectory_gt.txt", comments="#", ndmin=2)[:, 1:4]
    walked = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt, axis=0), axis=1))])
    rows = list(csv.DictReader(open(out / folder / "frames.csv")))
    return [{"frame": int(r["k"]), "metres": float(walked[min(int(r["k"]), len(walked) - 1)]),
             "parameters": int(r["parameters"]), "field_bytes": int(r["field_bytes"])}
            for r in rows if r["parameters"] != ""]


def summary(runs: list[dict]) -> list[dict]:
    out = []
    for name in dict.fromkeys(r["config"] for r in runs):
        rs = [r for r in runs if r["config"] == name]
        rec = {"config": name, "seeds": [r["seed"] for r in rs]}
        for key in ("ate_rmse_cm", "ate_odometry_cm", "loops", "accuracy_cm", "completion_cm", "completion_ratio_pct",
                    "fpt_s", "growths", "parameters"):
            vals = [r[key] for r in rs if r.get(key) is not None]
            rec[key] = {"values": vals, "mean": statistics.fmean(vals) if vals else None,
                        "std": statistics.stdev(vals) if len(vals) > 1 else None}
        out.append(rec)
    return out


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name, pts in curves.items():
        m = [p["metres"] for p in pts]
        axes[0].plot(m, [p["parameters"] / 1e6 for p in pts], label=name)
        axes[1].plot(m, [p["field_bytes"] / 2**20 for p in pts], label=name)
    axes[0].set_ylabel("parameters (millions)")
    axes[1].set_ylabel("field bytes (MiB)")
    for ax in axes:
        ax.set_xlabel("metres walked (ground truth)")
        ax.legend(fontsize=8)
    fig.suptitle("The map grows with the walk (synthetic walk, seed 0)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def table(summ: list[dict], curves: dict, st: dict, frames: int, seeds: int) -> str:
    def pm(s, d=2):
        if s["mean"] is None:
            return "-"
        return f"{s['mean']:.{d}f}" + ("" if s["std"] is None else f" ± {s['std']:.{d}f}")

    from _stamp import stamp_line

    lines = [f"{stamp_line(st)} Synthetic walk, first {frames} frames, seeds 0-{seeds - 1} (the fixed box: seed 0).",
             "",
             "| config | seeds | ATE RMSE cm | ATE odometry cm | loops | accuracy cm | completion cm | "
             "completion ratio % | growths | parameters at the end | field MiB at the end | metres walked | FPT s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summ:
        end = (curves.get(s["config"]) or [None])[-1]
        mib, walked = ("-", "-") if end is None else (f"{end['field_bytes'] / 2**20:.2f}", f"{end['metres']:.1f}")
        odo = s.get("ate_odometry_cm") or {"mean": None}
        loops = s.get("loops") or {"mean": None}
        lines.append(f"| {s['config']} | {len(s['seeds'])} | {pm(s['ate_rmse_cm'])} | {pm(odo)} | {pm(loops, 1)} | "
                     f"{pm(s['accuracy_cm'])} | "
                     f"{pm(s['completion_cm'])} | {pm(s['completion_ratio_pct'], 1)} | {pm(s['growths'], 1)} | "
                     f"{int(s['parameters']['mean']):,} | {mib} | {walked} | {pm(s['fpt_s'], 3)} |")
    return "\n".join(lines)


def loop_runs(out: Path) -> list[dict]:
    """The runs with loop closure that ``out``/walk_study.json lists."""
    return [r for r in json.loads((out / "walk_study.json").read_text())["runs"] if r.get("loops") is not None]


def mean_std(values: list[float]) -> list:
    """``[mean, std]`` rounded to 3 decimals (std None for a single value)."""
    return [round(statistics.mean(values), 3), round(statistics.stdev(values), 3) if len(values) > 1 else None]


def need_files(folder: Path, names: tuple[str, ...]) -> None:
    """Exit with the files a study needs that ``folder`` (a run of walk_study.json) lacks."""
    missing = [name for name in names if not (folder / name).is_file()]
    if missing:
        raise SystemExit(f"{folder}: no {', '.join(missing)}: the study reads the runs of walk_study.json in --out "
                         "(run the walk study into the same --out first)")


def loop_oracle(folder: Path) -> dict:
    """ATE (cm) of one run's tracker, its measured loops' correction and exact loops' (the ground truth's relative
    pose in each accepted loop; everything else as the run had it: keyframes, odometry edges, trusted flags)."""
    import numpy as np
    import torch

    from slam.config.load import load_config
    from slam.eval.ate import ate
    from slam.eval.trajectory import read_tum_trajectory
    from slam.loop.closer import LoopCloser

    need_files(folder, ("config.yaml", "checkpoint.pt", "trajectory_odometry.txt", "trajectory_gt.txt", "frames.csv"))
    cfg = load_config(str(folder / "config.yaml"))
    closer = LoopCloser(cfg.loops, None, cfg.seed)
    closer.load_state_dict(torch.load(folder / "checkpoint.pt", weights_only=False, map_location="cpu")["extra"][
        "run"]["loops"])
    odo, gt = (np.asarray(read_tum_trajectory(folder / f)[1], np.float64)
               for f in ("trajectory_odometry.txt", "trajectory_gt.txt"))
    with open(folder / "frames.csv") as fh:
        trusted = [row["trusted"] == "1" for row in csv.DictReader(fh)]
    n = min(len(odo), len(gt), len(trusted))
    odo, gt, trusted = odo[:n], gt[:n], trusted[:n]
    measured = closer.close_loops(odo, trusted)[0]
    errors = []
    for lp in closer.loops:
        exact = np.linalg.inv(gt[lp["match"]]) @ gt[lp["query"]]
        errors.append(round(float(np.linalg.norm((np.linalg.inv(exact) @ lp["rel"])[:3, 3])) * 100, 3))
        lp["rel"] = exact
    exact_loops = closer.close_loops(odo, trusted)[0]

    def cm(p):
        return round(ate(p[:, :3, 3], gt[:, :3, 3]).rmse * 100, 3)

    return {"run": folder.name, "loop_gt_error_cm": errors,
            "ate_cm": {"tracker": cm(odo), "measured loops": cm(measured), "exact loops": cm(exact_loops)}}


def oracle_study(out: Path) -> dict:
    """:func:`loop_oracle` of every run with loops in ``out``/walk_study.json, with mean ± std; written to
    ``out``/loop_oracle.json."""
    from _stamp import stamp

    runs = loop_runs(out)
    rows = [loop_oracle(out / r["folder"]) for r in runs]
    summary = {k: mean_std([r["ate_cm"][k] for r in rows]) for k in ("tracker", "measured loops", "exact loops")}
    result = {"stamp": stamp(), "command": f"python benchmarks/walk_study.py --loop-oracle --out {out}",
              "runs": rows, "mean_std_cm": summary}
    (out / "loop_oracle.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def refine_run(folder: Path, dest: Path, iters: int, on_tracker: bool) -> dict:
    """The global refinement (``loops.refine_iters``) of one finished run with loops, written before the refinement
    existed or with ``loops.refine_iters=0``: its checkpoint resumed into ``dest`` with ``iters`` (the run's last frame
    is done, so only the end of the run happens: the pose graph, the refinement, the mesh and its metrics; a
    run may not change ``loops.refine_iters`` on resume, this study may).
    ``on_tracker``: the control, the same iterations with the keyframes left at the tracker's poses and the mesh culled
    with them (the refinement alone, without the correction). Returns the reconstruction metrics (cm, %) and the
    refinement's statistics."""
    import shutil
    from unittest import mock

    import tdfields
    import slam.engine.refine as refine
    import slam.run.checkpoint as checkpoint
    from slam.config.validate import config_from_dict
    from slam.engine.view import RunView
    from slam.run.runner import resume_config, run_to_folder

    need_files(folder, ("checkpoint.pt", "config.yaml", "metrics.json"))
    dest.mkdir(parents=True, exist_ok=True)
    for name in ("checkpoint.pt", "config.yaml"):
        shutil.copy(folder / name, dest / name)
    if tdfields.load(dest / "checkpoint.pt")["extra"]["run"]["state"].get("refined") is not None:
        raise SystemExit(f"{folder}: its run refined the map already (map_refined in its metrics.json)")
    d = resume_config(dest).to_dict()
    d["loops"]["refine_iters"] = iters
    with mock.patch.object(refine, "move_keyframes", (lambda kfs, before, after: 0.0) if on_tracker
                           else refine.move_keyframes), \
            mock.patch.object(RunView, "map_poses", RunView.odometry_poses if on_tracker else RunView.map_poses), \
            mock.patch.object(checkpoint, "RESUME_KEYS", checkpoint.RESUME_KEYS + ("loops.refine_iters",)):
        m = run_to_folder(config_from_dict(d), dest, progress=False, resume=True)
    rec = m["reconstruction"]
    return {"run": folder.name, "poses": "tracker" if on_tracker else "corrected",
            "accuracy_cm": 100 * rec["accuracy_m"], "completion_cm": 100 * rec["completion_m"],
            "completion_ratio_pct": 100 * rec["completion_ratio"], "depth_l1_cm": 100 * rec["depth_l1_m"],
            "refined": m.get("map_refined")}


def refine_study(out: Path, iters: int) -> dict:
    """:func:`refine_run` of every run with loops in ``out``/walk_study.json, on the corrected poses and on the
    tracker's, beside the run's own metrics (no refinement); written to ``out``/refine.json."""
    from _stamp import stamp

    runs = loop_runs(out)
    rows = []
    for r in runs:
        rows.append(own_row(out / r["folder"]))
        for on_tracker in (False, True):
            rows.append(refine_run(out / r["folder"], out / "refine" / f"{Path(r['folder']).name}_"
                                   f"{'tracker' if on_tracker else 'corrected'}", iters, on_tracker))
    result = {"stamp": stamp(), "command": f"python benchmarks/walk_study.py --refine-study {iters} --out {out}",
              "iters": iters, "runs": rows, "mean_std": refine_summary(rows)}
    (out / "refine.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def own_row(folder: Path) -> dict:
    """A run's own reconstruction metrics (cm, %; None where it wrote no mesh), from its metrics.json."""
    need_files(folder, ("metrics.json",))
    rec = json.loads((folder / "metrics.json").read_text()).get("reconstruction") or {}
    cm = (lambda k: None if rec.get(k) is None else 100 * rec[k])
    return {"run": folder.name, "poses": "none (the run's own)", "accuracy_cm": cm("accuracy_m"),
            "completion_cm": cm("completion_m"), "completion_ratio_pct": cm("completion_ratio"),
            "depth_l1_cm": cm("depth_l1_m")}


def refine_summary(rows: list[dict]) -> dict:
    """Mean ± std per refinement (``poses``) of each metric, over the rows that have it."""
    summary = {}
    for poses in dict.fromkeys(row["poses"] for row in rows):
        got = [row for row in rows if row["poses"] == poses]
        summary[poses] = {k: mean_std(v) for k in ("accuracy_cm", "completion_cm", "completion_ratio_pct",
                                                   "depth_l1_cm")
                          for v in [[row[k] for row in got if row.get(k) is not None]] if v}
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1050, help="frames of the walk (1050: the way out, 20 m)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--mesh-resolution", type=float, default=0.04, help="marching-cubes cell (m) for the metrics")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "walk"))
    ap.add_argument("--continue", dest="resume", action="store_true",
                    help="keep the runs OUT/walk_study.partial.json already holds (same --frames) and run only the "
                    "missing (config, seed) pairs: a study too long for one sitting is spread over several, killed "
                    "at any time between runs or within one (that run is redone)")
    ap.add_argument("--from-partial", action="store_true", help="run nothing: summarise the runs a stopped study "
                    "finished (OUT/walk_study.partial.json; seeds outermost, so each finished seed has every config)")
    ap.add_argument("--loop-oracle", action="store_true", help="run nothing: re-solve the runs' pose graphs with "
                    "exact loops (see above); writes OUT/loop_oracle.json")
    ap.add_argument("--refine-study", type=int, metavar="ITERS", help="run only the end of each run with loops: "
                    "the global refinement of ITERS iterations on the corrected poses and, as the control, on the "
                    "tracker's (see above); writes OUT/refine.json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.loop_oracle:
        print(json.dumps(oracle_study(out)["mean_std_cm"]))
        return 0
    if args.refine_study is not None:
        print(json.dumps(refine_study(out, args.refine_study)["mean_std"]))
        return 0
    from _stamp import stamp

    import torch

    torch.set_num_threads(1)  # the stamp names the runs' thread count (threads: 1 in every preset), not this process's

    runs = []
    partial = out / "walk_study.partial.json"
    if args.from_partial:
        runs = json.loads(partial.read_text())
        last = max(r["seed"] for r in runs)  # a seed whose configs did not all finish is left out
        if {r["config"] for r in runs if r["seed"] == last} != {c for c in args.configs if "fixed" not in c}:
            runs = [r for r in runs if r["seed"] < last]
        args.seeds = max(r["seed"] for r in runs) + 1
    elif args.resume and partial.exists():
        runs = json.loads(partial.read_text())
        other = sorted({r.get("frames") for r in runs} - {args.frames}, key=str)
        if other:
            raise SystemExit(f"{partial}: runs of {other} frames, not --frames {args.frames}; another --out, or "
                             "remove the file")
    done = {(r["config"], r["seed"]) for r in runs}
    for seed in ([] if args.from_partial else range(args.seeds)):  # seeds outermost: see --from-partial
        for name in args.configs:
            if (name.endswith("fixed box") and seed > 0) or (name, seed) in done:
                continue
            rec = run(name, seed, args.frames, args.mesh_resolution, out)
            if seed == 0:  # kept with the run: a later sitting may not have this one's run folder
                rec["series"] = series(out, rec["folder"])
            runs.append(rec)
            partial.write_text(json.dumps(runs, indent=1))
    curves = {r["config"]: r.get("series") or series(out, r["folder"]) for r in runs if r["seed"] == 0}
    runs = [{k: v for k, v in r.items() if k != "series"} for r in runs]
    summ = summary(runs)
    st = stamp()
    (out / "walk_study.json").write_text(json.dumps({"stamp": st, "frames": args.frames, "runs": runs,
                                                     "summary": summ, "series": curves}, indent=1))
    if not (args.from_partial or args.resume):  # a --continue sitting leaves the next one its runs
        partial.unlink()
    plot(curves, out / "walk_study.png")
    text = table(summ, curves, st, args.frames, args.seeds)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
