"""The real-time default against the careful budget: frame time and ATE over seeds, per sequence, interleaved.

For each sequence, every seed runs the ``default`` variant (``lrslam run --data DIR``: the detected preset at the
device's default profile, realtime on the CPU) from ``--after`` and the references from ``--before`` (a checkout of
20b7b9c): ``quality``, tum/fr1_rpy-cpu's budget (which the quality profile reproduces), and on the synthetic
sequences also ``own``, their own careful preset, in turn, each in a fresh process with
one torch thread. The table gives per sequence the median frame time of each and their ratio, the median start-up
(kernel loads, the mapping process: ``preload_s``, not in the frame time), ATE mean ± std over the seeds (per-seed
values in the JSON), and frames lost.

Usage::

    git worktree add /tmp/w20 20b7b9c && git worktree add /tmp/after HEAD
    python benchmarks/profile_targets.py --before /tmp/w20 --after /tmp/after --seeds 5 \\
        --out benchmarks/results/profile_targets

``--loops`` measures loop closure instead: the reference is the default itself with ``loops.enabled=true`` (from
``--after``; no ``--before``), and the table gives both frame times and their ratio, both ATEs (with loops: the
corrected trajectory's) and the paired difference, the loops and candidates a seed, and the largest error of an
accepted loop against the ground truth (a false loop shows there); on a TUM folder also with the ground truth taken
at the time offset that fits it to the tracker's own motion (``_gt_timing.py``: the motion capture's clock against
the images', which moves a loop's error by 0.5-0.7 degrees per 10 ms where fr1_rpy turns fastest)::

    python benchmarks/profile_targets.py --loops --seeds 5 --out benchmarks/results/loops_dev

``--table-only`` rewrites the table from the JSON. The column "default - quality" is the mean of the per-seed
differences with the half-width of their 95 % t interval: an interval that holds 0 means the seeds do not resolve
a difference. Sequences (``--sequences``): ``gentle`` and ``fast`` (the fr1_rpy windows in ``../shared/data``), ``dev_range``
(both windows as one folder, pairs 0-224, linked into ``--out``), ``room`` (the bundled synthetic room), ``walk300``
(the synthetic walk's first 300 frames). Writes ``profile_targets.json`` and ``profile_targets.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _gt_timing import analyse, tum_folder, worst  # noqa: E402
from before_after import absolute_paths, run_variant  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LRSLAM_SHARED_DATA", ROOT.parent / "shared" / "data"))
WINDOWS = ("tum_fr1_rpy_0_124", "tum_fr1_rpy")


def merge_tum_windows(folders: list[Path], dest: Path) -> Path:
    """One TUM folder of several windows of a sequence (images linked, lists merged in time order; their
    associations too when each window has them, so the folder holds every pair the windows hold)."""
    for sub in ("rgb", "depth"):
        (dest / sub).mkdir(parents=True, exist_ok=True)
        for f in folders:
            for img in (f / sub).glob("*.png"):
                link = dest / sub / img.name
                if not link.exists():
                    link.symlink_to(img.resolve())
    lists = ["rgb.txt", "depth.txt", "groundtruth.txt"]
    if all((f / "associations.txt").is_file() for f in folders):  # the windows' own pairs, every one of them
        lists.append("associations.txt")
    for name in lists:
        rows = sorted({line for f in folders for line in (f / name).read_text().splitlines()
                       if line.strip() and not line.startswith("#")}, key=lambda r: float(r.split()[0]))
        (dest / name).write_text("".join(f"{r}\n" for r in rows))
    return dest


#: tum/fr1_rpy-cpu's budget where it differs from the synthetic presets' own (20b7b9c)
TUM_CPU_BUDGET = ["tracking.iters=20", "tracking.lr_t=0.01", "tracking.lr_r=0.002", "mapping.every_frame=1",
                  "mapping.keyframe_every=1", "mapping.iters=10", "mapping.iters_first=60"]


def sequences(out: Path) -> dict[str, tuple[list[str], dict[str, list[str]]]]:
    """name -> (arguments of the default run, {reference: arguments of a careful 20b7b9c run}). The reference
    ``quality`` is tum/fr1_rpy-cpu's budget everywhere; the synthetic sequences also have ``own``, their own
    careful preset (mapping every 4th frame)."""
    gentle, fast = SHARED / WINDOWS[1], SHARED / WINDOWS[0]
    dev = out / "data" / "tum_fr1_rpy_0_224"
    tum = lambda d: ([f"--data={d}"], {"quality": ["--config", "tum/fr1_rpy-cpu", f"--data={d}"]})  # noqa: E731
    walk = ["--config", "synthetic/walk", "data.max_frames=300"]
    return {"gentle": tum(gentle), "fast": tum(fast), "dev_range": tum(dev),
            "room": ([], {"quality": ["--config", "synthetic", *TUM_CPU_BUDGET], "own": ["--config", "synthetic"]}),
            "walk300": (walk, {"quality": [*walk, *TUM_CPU_BUDGET], "own": walk})}


def with_loops(seqs: dict) -> dict:
    """The sequences with one reference each, ``loops``: the default's own arguments with loop closure on."""
    return {name: (args, {"loops": [*args, "loops.enabled=true"]}) for name, (args, _) in seqs.items()}


def summary(runs: list[dict]) -> dict:
    ok = [r for r in runs if "error" not in r]
    if not ok:
        return {"errors": [r["error"] for r in runs]}
    ates = [r["ate_rmse_cm"] for r in ok]
    if any("loops" in r for r in ok):
        errs = [r["loop_gt_error_max"] for r in ok if r.get("loop_gt_error_max")]
        timings = [r["gt_timing"] for r in ok if r.get("gt_timing")]
        return {**summary([{k: v for k, v in r.items() if k != "loops"} for r in ok]),
                "loops": [r["loops"] for r in ok], "loop_candidates": [r["loop_candidates"] for r in ok],
                "ate_odometry_cm": [r["ate_odometry_cm"] for r in ok],
                "loop_gt_error_max": [max(e[0] for e in errs), max(e[1] for e in errs)] if errs else None,
                "gt_offset_ms": [t["fitted_offset_ms"] for t in timings] or None,
                "loop_gt_error_max_fitted_offset": worst(timings, "fitted_offset") if timings else None}
    return {"fpt_s": statistics.median(r["fpt_s"] for r in ok), "preload_s": statistics.median(r["preload_s"] for r in ok),
            "wall_s": statistics.median(r["wall_s"] for r in ok), "ate_cm_mean": statistics.mean(ates),
            "ate_cm_std": statistics.stdev(ates) if len(ates) > 1 else 0.0, "ate_cm": ates,
            "frames_lost": [r["frames_lost"] for r in ok], "failed": len(runs) - len(ok)}


def paired(result_row: dict, ref: str, sign: float = 1.0) -> str:
    """Default minus reference ATE over the seeds both finished (``sign`` -1: reference minus default): mean ± the
    95 % interval's half-width (t)."""
    runs = result_row["runs"]
    ref_by_seed = {r["seed"]: r["ate_rmse_cm"] for r in runs[ref] if "error" not in r}
    diffs = [sign * (r["ate_rmse_cm"] - ref_by_seed[r["seed"]]) for r in runs["default"]
             if "error" not in r and r["seed"] in ref_by_seed]
    if len(diffs) < 2:
        return "-"
    t95 = {2: 12.71, 3: 4.30, 4: 3.18, 5: 2.78, 6: 2.57, 7: 2.45, 8: 2.36, 9: 2.31, 10: 2.26}.get(len(diffs), 2.0)
    half = t95 * statistics.stdev(diffs) / len(diffs) ** 0.5
    return f"{statistics.mean(diffs):+.2f} ± {half:.2f}"


def _head(result: dict, command: str, columns: list[str]) -> list[str]:
    """A table's stamp line and its header rows."""
    s = result["stamp"]
    return [f"Measured {s['date']} on {s['cpu']} (2 cores), {result['seeds']} seeds, one torch thread per process, "
            f"`{command}`.", "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def loops_table(result: dict) -> str:
    """The ``--loops`` table: the default without and with loop closure, per sequence."""
    lines = _head(result, "python benchmarks/profile_targets.py --loops",
                  ["sequence", "frames", "s/frame", "with loops s/frame", "ratio", "ATE cm", "with loops ATE cm",
                   "with - without, 95 %", "loops a seed", "candidates a seed", "worst loop against ground truth",
                   "the same, ground truth at the fitted time offset (median offset)", "frames lost"])
    for name, row in result["sequences"].items():
        d, w = row["default"], row["references"]["loops"]
        if "fpt_s" not in d or "fpt_s" not in w:
            lines.append(f"| {name} | failed: {d.get('errors') or w.get('errors')} ||||||||||||")
            continue
        gt = w["loop_gt_error_max"]
        gt = f"{100 * gt[0]:.2f} cm, {gt[1]:.2f}°" if gt else "no loop"
        fit = w.get("loop_gt_error_max_fitted_offset")
        fit = f"{100 * fit[0]:.2f} cm, {fit[1]:.2f}° ({statistics.median(w['gt_offset_ms']):+.1f} ms)" if fit else "-"
        lines.append(f"| {name} | {row['frames']} | {d['fpt_s']:.3f} | {w['fpt_s']:.3f} | {w['fpt_s'] / d['fpt_s']:.2f} | "
                     f"{d['ate_cm_mean']:.2f} ± {d['ate_cm_std']:.2f} | {w['ate_cm_mean']:.2f} ± {w['ate_cm_std']:.2f} | "
                     f"{paired(row, 'loops', -1.0)} | {statistics.mean(w['loops']):.1f} | "
                     f"{statistics.mean(w['loop_candidates']):.0f} | {gt} | {fit} | "
                     f"{max(d['frames_lost'])} / {max(w['frames_lost'])} |")
    return "\n".join(lines)


def table(result: dict) -> str:
    if result.get("loops"):
        return loops_table(result)
    lines = _head(result, "python benchmarks/profile_targets.py",
                  ["sequence", "frames", "default s/frame", "quality (20b7b9c) s/frame", "ratio", "default start-up s",
                   "default ATE cm", "quality ATE cm", "default - quality, 95 %", "frames lost"])
    for name, row in result["sequences"].items():
        d = row["default"]
        for ref, q in row["references"].items():
            label = name if ref == "quality" else f"{name} (against its own preset)"
            if "fpt_s" not in d or "fpt_s" not in q:
                lines.append(f"| {label} | failed: {d.get('errors') or q.get('errors')} ||||||||")
                continue
            lines.append(f"| {label} | {row['frames']} | {d['fpt_s']:.3f} ({1 / d['fpt_s']:.1f}/s) | {q['fpt_s']:.3f} | "
                         f"{d['fpt_s'] / q['fpt_s']:.2f} | {d['preload_s']:.1f} | {d['ate_cm_mean']:.2f} ± "
                         f"{d['ate_cm_std']:.2f} | {q['ate_cm_mean']:.2f} ± {q['ate_cm_std']:.2f} | "
                         f"{paired(row, ref)} | {max(d['frames_lost'])} / {max(q['frames_lost'])} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", help="a checkout of 20b7b9c (git worktree add /tmp/w20 20b7b9c); not with --loops")
    ap.add_argument("--loops", action="store_true", help="the default without and with loop closure, from --after")
    ap.add_argument("--after", default=str(ROOT), help="the checkout measured (default: this one)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--sequences", nargs="+", default=["gentle", "fast", "dev_range", "room", "walk300"])
    ap.add_argument("--set", nargs="*", default=[], help="key=value overrides for both variants (toy runs)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--table-only", action="store_true", help="rewrite the table from OUT/profile_targets.json")
    args = ap.parse_args(argv)
    out = Path(args.out).resolve()
    if args.table_only:
        text = table(json.loads((out / "profile_targets.json").read_text()))
        (out / "profile_targets.md").write_text(text + "\n")
        print(text)
        return 0
    out.mkdir(parents=True, exist_ok=True)
    if "dev_range" in args.sequences:
        merge_tum_windows([SHARED / w for w in WINDOWS], out / "data" / "tum_fr1_rpy_0_224")
    seqs = with_loops(sequences(out)) if args.loops else sequences(out)
    unknown = sorted(set(args.sequences) - set(seqs))
    if unknown or args.seeds < 1 or not (args.loops or args.before):
        raise SystemExit(f"profile_targets: error: unknown sequences {unknown}, --seeds < 1, or neither --before "
                         "nor --loops")
    sys.path.insert(0, str(ROOT))
    from _stamp import stamp

    result = {"stamp": stamp(), "command": " ".join(sys.argv), "seeds": args.seeds, "loops": args.loops,
              "sequences": {}}
    for name in args.sequences:
        default_args, references = seqs[name]
        ref_checkout = args.after if args.loops else args.before
        variants = [("default", args.after, default_args), *((ref, ref_checkout, a) for ref, a in references.items())]
        runs = {variant: [] for variant, _, _ in variants}
        for seed in range(args.seeds):
            for variant, checkout, extra in variants:
                v = {"name": f"{name}-{variant}-s{seed}", "checkout": str(Path(checkout).resolve()),
                     "args": absolute_paths(["--no-mesh", *extra, f"seed={seed}", *args.set])}
                rec = run_variant(v, out, 0)
                if "error" not in rec:
                    m = json.loads((out / "runs" / f"{v['name']}-r0" / "metrics.json").read_text())
                    rec.update(preload_s=m.get("preload_s") or 0.0, frames_lost=m.get("frames_lost", 0), seed=seed)
                    if m.get("loops") is not None:
                        lp, odo = m["loops"], m.get("ate_odometry_rmse_m")
                        rec.update(loops=lp["loops"], loop_candidates=lp["candidates_tried"],
                                   ate_odometry_cm=None if odo is None else 100 * odo,
                                   loop_gt_error_max=[lp["gt_error_max_m"], lp["gt_error_max_deg"]]
                                   if "gt_error_max_m" in lp else None)
                        if (tum := tum_folder(v["args"])) is not None:
                            rec["gt_timing"] = analyse(out / "runs" / f"{v['name']}-r0", tum)
                runs[variant].append(rec)
        frames = next((r["num_frames"] for r in runs["default"] if "num_frames" in r), None)
        result["sequences"][name] = {"frames": frames, "args": {"default": default_args, **references},
                                     "default": summary(runs["default"]),
                                     "references": {ref: summary(runs[ref]) for ref in references}, "runs": runs}
        (out / "profile_targets.json").write_text(json.dumps(result, indent=1) + "\n")
    text = table(result)
    (out / "profile_targets.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
