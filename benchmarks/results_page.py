"""Write docs/results.md, the page of current numbers, from the committed JSON under benchmarks/results/.

    python benchmarks/results_page.py            # rewrite docs/results.md
    python benchmarks/results_page.py --check    # exit 1 when docs/results.md is not what the JSON gives

Nothing is measured here: each section renders one benchmark's committed output with that benchmark's own table
function, headed by the stamp (date, version, CPU) of the run that measured it and the command that reproduces
it. A result lands by committing the benchmark's JSON and re-running this script; the test
(tests/benchmarks/test_results_page.py) fails while the page is stale, and while a folder under
benchmarks/results/ is cited by no docs page.
"""

from __future__ import annotations

import argparse
import difflib
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
#: said of a table measured before the realtime profile's mapping tail weight went from 10 to 50 and before depth
#: ICP's plane gate (docs/robustness.md)
PAGE = ROOT / "docs" / "results.md"


def _json(rel: str) -> dict:
    return json.loads((RESULTS / rel).read_text())


def _stamp_line(st: dict) -> str:
    """One line from either stamp layout (benchmarks/_stamp.py's or slam_compare.py's)."""
    version = st.get("tdfields_version") or st.get("version", "?")
    torch = st.get("torch_version") or st.get("torch")
    return f"Measured {st['date']} with tdfields {version}{f', torch {torch}' if torch else ''}, on {st['cpu']}."


def _source(rel: str, command: str) -> str:
    return f"Source: `benchmarks/results/{rel}`. Reproduce: `{command}`."


def parameters() -> str:
    """Parameter counts of the paper's Table 1 scenes, computed from the presets' published boxes (no run)."""
    from slam.config import load_config
    from slam.model.scene import SceneModel, parameter_counts, scene_aabb

    lines = ["Computed from the presets' published boxes by `lrslam params --config PRESET representation=NAME` "
             "(closed forms: no run, no stamp). They equal the LRSLAM paper's Table 1; TUM has one decoder "
             "parameter fewer because ESLAM's beta is fixed there.", "",
             "| scene (preset) | representation | geometry | appearance | decoders | total |", "|---|---|---|---|---|---|"]
    for preset in ("replica/room0", "scannet/scene0000", "tum/fr1_desk"):
        for rep in ("lrslam", "eslam"):
            cfg = load_config(preset, [f"representation={rep}"], profile="paper")
            c = parameter_counts(SceneModel(cfg, scene_aabb(cfg.scene.bound, cfg.scene.bound_dividable)))
            lines.append(f"| {preset} | {rep} | {c['geometry']:,} | {c['appearance']:,} | {c['decoders']:,} | "
                         f"{c['total']:,} ({c['total'] / 1e6:.2f}M) |")
    return "\n".join(lines)


def memory_growth() -> str:
    import memory_growth as m

    d = _json("memory_growth.json")
    return "\n".join([
        "Parameters and peak training memory of each kind as the scene's side L grows (cell 5 cm, 8 channels, "
        "3 Adam steps on 40k points, the reference path). The slopes are the exponents of L fitted on the largest "
        "sizes: 3 for a dense grid, 2 for planes, 1 for CP.", "",
        m.markdown(d["rows"], d["exponents"], _stamp_line(d["stamp"])), "",
        "![memory growth](images/memory_growth.png)", "",
        _source("memory_growth.json", "python benchmarks/memory_growth.py --out benchmarks/results")])


def field_speed() -> str:
    import field_speed_table as m

    d = _json("field_speed.json")
    d.setdefault("threads", 1)  # the published run's --threads (pytest-benchmark's JSON does not record it)
    return "\n".join([
        "Forward and forward+backward time per query of 40k points at the Replica room0 configurations, with the "
        "fused kernels and with the pure-PyTorch reference path; ESLAM's `grid_sample` tri-plane as the baseline.",
        "", m.table(d, "0.1.0"), "",
        _source("field_speed.json", "pytest benchmarks/test_field_speed.py --benchmark-enable --benchmark-json "
                "benchmarks/results/field_speed.json; python benchmarks/field_speed_table.py "
                "benchmarks/results/field_speed.json --threads 1")])


def slam_accuracy() -> str:
    import slam_compare as m

    parts = ["Absolute trajectory error over 5 seeds (mean ± sample std, and each seed), median frame time and "
             "parameters: LRSLAM (CP geometry, Six-axis appearance) against ESLAM's tri-planes and CP for both, run "
             "from the same code with `representation=NAME`. One thread per run, one run at a time."]
    for rel, what in (("accuracy_final/slam_compare.json", "The fr1_rpy windows, at the `quality` profile's budget"),
                      ("synthetic_seeds/slam_compare.json", "The synthetic room"),
                      ("synthetic_noise5cm_seeds/slam_compare.json", "The synthetic room, depth noise 5 cm")):
        d = _json(rel)
        parts += ["", f"**{what}.**", "", m.markdown(d["summary"], d["stamp"], d["command"]).rstrip(), "",
                  f"Source: `benchmarks/results/{rel}`."]
    return "\n".join(parts)


def profiles() -> str:
    import profile_targets as m

    d = _json("profile_targets/profile_targets.json")
    return "\n".join([
        "The default (`lrslam run --data DIR`, the `realtime` profile) against the careful CPU budget of 20b7b9c "
        "(`--profile quality`), each seed's runs in turn in fresh processes. Frame time excludes start-up (the "
        "kernels' load and the mapping process, reported apart). The last columns: the mean per-seed difference in "
        "ATE with its 95 % interval, and frames lost. `gentle` and `fast` are the fr1_rpy windows (pairs 125-224 "
        "and 0-124), `dev_range` pairs 0-224, `room` the bundled synthetic room, `walk300` the synthetic walk's "
        "first 300 frames. On the fr1_rpy data the reference is 20b7b9c's `tum/fr1_rpy-cpu`, whose box stayed fixed "
        "(`scene.grow=false`): today's `--profile quality` with the box growing, as `--data` gives it, ends the fast "
        "window at 2.75 ± 0.11 cm, as the default does (`profile_targets/fast_window_gap.json`).",
        "", m.table(d), "",
        _source("profile_targets/profile_targets.json",
                "python benchmarks/profile_targets.py --before <a worktree of 20b7b9c> --seeds 5 "
                "--out benchmarks/results/profile_targets")])


#: the real-time replay's runs: (window label or None for the folder's name, setting, file, its command's options)
REALTIME_RUNS = [
    (None, "free, odometry (default)", "default", ""),
    (None, "free, odometry, `tracking.icp_wide=0`", "icp_wide_off", "--set tracking.icp_wide=0 "),
    (None, "free, wait", "warmup_wait", "--set mapping.realtime_warmup=wait "),
    (None, "schedule", "schedule", "--set mapping.realtime_sync=schedule "),
    ("room", "free, odometry (default)", "room_default", "--config synthetic --data bundled "),
    ("room", "free, wait", "room_warmup_wait", "--config synthetic --data bundled --set mapping.realtime_warmup=wait "),
    ("walk300", "free, odometry (default)", "walk300_default", "--config synthetic/walk --data bundled --set "
                                                               "data.max_frames=300 "),
    ("walk300", "free, wait", "walk300_warmup_wait", "--config synthetic/walk --data bundled --set "
                                                     "mapping.realtime_warmup=wait data.max_frames=300 "),
] + [(label, setting, f"room_{variant}_{name}", f"--config synthetic --data bundled --set "
                                                f"mapping.realtime_warmup={mode} {options} ")
     for variant, label, options in (
         ("seed3_holes", "room, data seed 3, depth holes", "data.options.seed=3 data.options.sensor_holes=true"),
         ("fast2x", "room, twice as fast", "data.options.loop_frames=200"),
         ("size240", "room at 240x320", "data.options.height=240 data.options.width=320"))
     for setting, name, mode in (("free, odometry (default)", "default", "odometry"),
                                 ("free, wait", "warmup_wait", "wait"))]


def realtime() -> str:
    runs = [(label, setting, name, opts, _json(f"realtime_replay/{name}.json"))
            for label, setting, name, opts in REALTIME_RUNS]
    lines = ["`lrslam run --data DIR --realtime` replays a folder at its recorded rate (30 Hz): a frame that arrives "
             "while the system is busy is dropped, and the newest is processed next. `mapping.realtime_sync`: `free` "
             "tracks on while the mapper is busy and maps only when it is free, `schedule` keeps the recorded run's "
             "schedule (the tracker waits for the call of two frames before). `mapping.realtime_warmup` (with "
             "`free`): `odometry` tracks the frames that arrive while the first map is built by depth ICP, `wait` "
             "waits for it. The fr1_rpy windows (tum_fr1_rpy: pairs 125-224, tum_fr1_rpy_0_124: pairs 0-124), the "
             "bundled synthetic room, the synthetic walk's first 300 frames and the room made by the generator with "
             "other textures and Kinect-like depth holes, a camera twice as fast and images four times as large. "
             "Mean ± std over seeds, the longest latency over all seeds; every row measured on the same machine, one after "
             "the other.", "",
             _stamp_line(runs[0][4]["stamp"]), "",
             "| window | `realtime_sync`, `realtime_warmup` | seeds | frames processed | dropped | latency s, median / "
             "95th percentile / longest | mapping calls / declined | frames lost | ATE over the processed frames, cm | "
             "per seed |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    rows = []
    for order, (label, setting, _, _, d) in enumerate(runs):
        for i, (seq_name, seq) in enumerate(d["sequences"].items()):
            s, rs = seq["summary"], seq["runs"]
            per_seed = ", ".join(f"{r['ate_rmse_cm']:.1f}" for r in rs)
            calls = (f"{s['mapping_calls']['mean']:.1f} / {s['mapping_declined']['mean']:.1f}"
                     if "mapping_calls" in s else "")
            rows.append(((label or "", i, order), f"| {label or seq_name} | {setting} | {len(rs)} | "
                         f"{s['frames_processed']['mean']:.1f} ± {s['frames_processed']['std']:.1f} | "
                         f"{s['frames_dropped']['mean']:.1f} | {s['latency_median_s']['mean']:.3f} / "
                         f"{s['latency_p95_s']['mean']:.3f} / {max(r['latency_max_s'] for r in rs):.2f} | {calls} | "
                         f"{sum(r['frames_lost'] for r in rs)} | {s['ate_rmse_cm']['mean']:.1f} ± "
                         f"{s['ate_rmse_cm']['std']:.1f} | {per_seed} |"))
    lines += [row for _, row in sorted(rows, key=lambda r: r[0])]
    for _, _, name, opts, _ in runs:
        lines += ["", _source(f"realtime_replay/{name}.json", f"python benchmarks/realtime_replay.py {opts or '--config tum '}"
                                                                f"--seeds 5 --out benchmarks/results/realtime_replay/{name}.json")]
    return "\n".join(lines)


def walk() -> str:
    import walk_study as m

    d = _json("walk_hold/walk_study.json")
    seeds = max(r["seed"] for r in d["runs"]) + 1
    return "\n".join([
        "The synthetic walk (`--config synthetic/walk`): 2100 frames, 40 m out through rooms and back, the box "
        "growing with the camera. Frame times are left out: two runs shared the machine's two cores.", "",
        m.table(d["summary"], d["series"], d["stamp"], d["frames"], seeds), "",
        "![parameters and bytes over the whole walk](images/walk_hold.png)", "",
        _source("walk_hold/walk_study.json", "python benchmarks/walk_study.py --frames 2100 --seeds 5 --configs "
                "lrslam eslam --continue --out benchmarks/results/walk_hold")])


def walk_loops() -> str:
    import walk_study as m

    d = _json("walk_loops/walk_study.json")
    seeds = max(r["seed"] for r in d["runs"]) + 1
    per_seed = ", ".join(f"seed {r['seed']}: {r['ate_odometry_cm']:.2f} -> {r['ate_rmse_cm']:.2f} cm, {r['loops']} loops "
                         f"of {r['loop_candidates']} candidates" for r in d["runs"])
    return "\n".join([
        "The synthetic walk at the default profile with loop closure (`loops.enabled=true`, docs/loops.md): the "
        "tracker's ATE (odometry) and the pose graph's (ATE RMSE). The loops' cost in frame time is measured "
        "against runs without them in the dev-sequence table below.", "",
        m.table(d["summary"], d["series"], d["stamp"], d["frames"], seeds), "", f"Per seed: {per_seed}.", "",
        _source("walk_loops/walk_study.json", "python benchmarks/walk_study.py --frames 2100 --seeds 5 --configs "
                "'lrslam, loops' --mesh-resolution 0.04 --out benchmarks/results/walk_loops"), "",
        refinement()])


def refinement() -> str:
    d = _json("walk_loops/refine.json")
    names = {"corrected": "on the corrected poses (what a run does)", "tracker": "on the tracker's poses (control)"}

    def pm(v):
        return "-" if v is None else f"{v[0]:.2f} ± {v[1]:.2f}"

    rows = ["| refinement | accuracy cm | completion cm | completion ratio % | depth L1 cm | seconds |", "|---|---|---|"
            "---|---|---|"]
    for poses, st in d["mean_std"].items():
        secs = [r["refined"]["seconds"] for r in d["runs"] if r["poses"] == poses and r.get("refined")]
        rows.append(f"| {names.get(poses, 'none (the runs above)')} | {pm(st.get('accuracy_cm'))} | "
                    f"{pm(st.get('completion_cm'))} | {pm(st.get('completion_ratio_pct'))} | "
                    f"{pm(st.get('depth_l1_cm'))} | {f'{statistics.median(secs):.1f}' if secs else '-'} |")
    return "\n".join([
        f"The global refinement (`loops.refine_iters={d['iters']}`, docs/loops.md) on the same runs' ends: each run's "
        "last checkpoint resumed, so only the pose graph, the refinement and the mesh run again. The control re-fits "
        "as long on the tracker's poses, so the difference between the last two rows is what the loops' correction "
        "does to the map. Mean ± std over the seeds; median seconds of the refinement.", "",
        _stamp_line(d["stamp"]), "",
        *rows, "", _source("walk_loops/refine.json", d["command"])])


def loops_dev() -> str:
    import profile_targets as m

    d = _json("loops_dev/profile_targets.json")
    return "\n".join([
        "The default (`lrslam run --data DIR`, the `realtime` profile) without and with loop closure "
        "(`loops.enabled=true`), each seed's two runs in turn in fresh processes: frame time (start-up apart), ATE "
        "(with loops: the corrected trajectory's) and the mean per-seed difference with its 95 % interval, the loops "
        "accepted and the candidates verified a seed, and the accepted loop that disagreed most with the ground "
        "truth over all seeds. `gentle` and `fast` are the fr1_rpy windows (pairs 125-224 and 0-124), `dev_range` "
        "pairs 0-224, `room` the bundled synthetic room, `walk300` the synthetic walk's first 300 frames.", "",
        m.table(d), "",
        _source("loops_dev/profile_targets.json",
                "python benchmarks/profile_targets.py --loops --seeds 5 --out benchmarks/results/loops_dev")])


def memory_rss() -> str:
    import memory_rss as m

    parts = ["Resident memory of a whole run sampled every few frames: the keyframes beyond the in-memory budget "
             "spill to disk, so memory stops growing with the run."]
    for rel, title, image, cmd in (
            ("memory_rss_5000/memory_rss.json", "The synthetic room looped to 5000 frames", "memory_rss_5000.png",
             "python benchmarks/memory_rss.py --sequence room --frames 5000 --every 250 --after 500 --settings after "
             "--out benchmarks/results/memory_rss_5000"),
            ("memory_rss_tum/memory_rss.json", "TUM fr1_rpy pairs 0-224 forth and back to 400 frames",
             "memory_rss_tum.png",
             "python benchmarks/memory_rss.py --sequence tum-loop --frames 400 --every 25 --settings before after "
             "--presets tum/fr1_rpy-cpu tum/fr1_rpy-eslam-cpu --out benchmarks/results/memory_rss_tum")):
        d = _json(rel)
        parts += ["", m.table(d["results"], d["stamp"], title), "", f"![{title}](images/{image})", "",
                  _source(rel, cmd)]
    return "\n".join(parts)


def meshing() -> str:
    import memory_rss as m

    d = _json("walk_mesh/mesh_rss.json")
    return "\n".join([
        "`lrslam mesh` of a whole walk at 2 cm: one dense volume over the marching-cubes bound "
        "(`meshing.block_cells=0`, the reference) against the blocks near the keyframes' depth (the default), "
        "culled and written the same way; accuracy and completion against the walk's ground-truth mesh with the "
        "run's own protocol ([how LRSLAM works](slam.md), Meshing). Both meshes are of the run's one map; its "
        f"trajectory's ATE RMSE was {100 * d['run_ate_rmse_m']:.2f} cm.", "",
        m.mesh_table(d), "",
        _source("walk_mesh/mesh_rss.json", "lrslam run --config synthetic/walk --out runs/walk --no-mesh && "
                "python benchmarks/memory_rss.py --mesh runs/walk --mesh-name 'the 2100-frame synthetic walk (seed 0, "
                "realtime profile)' --resolution 0.02 --block-cells 0 32 --out benchmarks/results/walk_mesh")])


def robustness() -> str:
    nd = _json("no_depth/no_depth_study.json")
    lines = [f"**Frames without depth, tracked on colour.** Measured {nd['date']} with tdfields {nd['version']} on "
             f"{nd['cpu']}, `{nd['config']}`: frames {', '.join(map(str, nd['drop']))} of each window had their depth "
             "removed. `predict` extrapolates the motion, `color` tracks on colour alone (the default).", "",
             "| window | mode | seeds | ATE over the depthless frames cm | ATE over all frames cm |", "|---|---|---|---|---|"]
    for s in nd["summary"]:
        lines.append(f"| {s['sequence']} | {s['mode']} | {s['seeds']} | {s['ate_dropped_cm']['mean']:.2f} ± "
                     f"{s['ate_dropped_cm']['std']:.2f} | {s['ate_cm']['mean']:.2f} ± {s['ate_cm']['std']:.2f} |")
    lines += ["", _source("no_depth/no_depth_study.json", "python benchmarks/no_depth_study.py --seeds 5 --data "
                          "../shared/data/tum_fr1_rpy ../shared/data/tum_fr1_rpy_0_124 --out benchmarks/results/no_depth")]
    ri = _json("resume_identity/slam_compare.json")
    runs = ri["runs"] + ri["sequential_runs"]
    same = sum(r["identical"] for r in runs)
    lines += ["", f"**Interrupted and resumed runs.** {_stamp_line(ri['stamp'])} Each run was stopped by SIGINT after "
              f"frame {runs[0]['interrupted_after']} and resumed with `--resume`; {same} of {len(runs)} resumed "
              "trajectories are byte-identical to the uninterrupted run's (both loop modes, 5 seeds).", "",
              _source("resume_identity/slam_compare.json", "python " + ri["command"])]
    return "\n".join(lines)


def nerf() -> str:
    import nerf_encodings as ne
    import psnr_budget as pb

    d = _json("nerf_encodings/nerf_encodings.json")
    p = _json("psnr_budget/psnr_budget.json")
    s = d["settings"]
    return "\n".join([
        "**tdfields encodings against nerfstudio's.** " + d["stamp_line"] + f" nerfstudio {d['nerfstudio'] or 'not installed'}; "
        f"speed at {', '.join(map(str, s['threads']))} threads, {s['points']:,} points.", "", ne.tables(d), "",
        "![PSNR and speed of each encoding pair](images/nerf_encodings.png)", "",
        _source("nerf_encodings/nerf_encodings.json", "python benchmarks/nerf_encodings.py (with nerfstudio "
                "importable: docs/nerf.md)"), "",
        "**PSNR against parameters** on the synthetic room, each kind at several budgets.", "", pb.markdown(p), "",
        "![PSNR against parameters](images/psnr_budget.png)", "",
        _source("psnr_budget/psnr_budget.json", "python benchmarks/psnr_budget.py --seeds 3 --out "
                "benchmarks/results/psnr_budget")])


def gpu() -> str:
    text = (RESULTS / "gpu_check_h200" / "gpu_check.md").read_text().rstrip()
    return "\n".join([
        "The prepared GPU check (`bash benchmarks/gpu_check.sh --data DIR --out OUT`) on the last GPU this project "
        "was lent. A step marked timeout did not finish in its share of the loan.", "", text, "",
        _source("gpu_check_h200/", "bash benchmarks/gpu_check.sh --data shared/data/tum_fr1_rpy --out OUT")])


#: docs/images/NAME <- the figure a benchmark wrote beside its JSON (copied when the page is written)
FIGURES = {"memory_growth.png": "memory_growth.png", "walk_hold.png": "walk_hold/walk_study.png",
           "memory_rss_5000.png": "memory_rss_5000/memory_rss.png", "memory_rss_tum.png": "memory_rss_tum/memory_rss.png",
           "psnr_budget.png": "psnr_budget/psnr_budget.png", "nerf_encodings.png": "nerf_encodings/nerf_encodings.png"}

SECTIONS = (("Parameters", parameters), ("Memory growth", memory_growth), ("Field query speed", field_speed),
            ("SLAM accuracy and frame time", slam_accuracy), ("Profiles", profiles), ("Real-time replay", realtime),
            ("The long walk", walk), ("Loop closure on the walk", walk_loops),
            ("Loop closure on the dev sequences", loops_dev), ("Memory over a long run", memory_rss),
            ("Meshing memory", meshing), ("Robustness", robustness), ("NeRF", nerf), ("GPU", gpu))


def render() -> str:
    """The page: each section renders with its benchmark's own table function (their modules importable for it)."""
    added = [p for p in (str(ROOT), str(ROOT / "benchmarks")) if p not in sys.path]
    sys.path[:0] = added
    try:
        return _render()
    finally:
        for p in added:
            sys.path.remove(p)


def _render() -> str:
    head = ("# Results\n\nCurrent numbers only. Every table on this page is generated from committed JSON under "
            "`benchmarks/results/` by `python benchmarks/results_page.py`, and each carries the stamp (date, "
            "version, CPU) of the run that measured it. Accuracy is mean ± sample std over seeds with every seed's "
            "value kept in the JSON. Frame times are medians on a 2-core machine; compare only numbers measured side "
            "by side. What each benchmark measures and how to run it: [benchmarks](benchmarks.md).\n")
    return head + "".join(f"\n## {title}\n\n{fn().rstrip()}\n" for title, fn in SECTIONS)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 when docs/results.md is stale")
    args = ap.parse_args(argv)
    text = render()
    images = ROOT / "docs" / "images"
    if args.check:
        old = PAGE.read_text() if PAGE.exists() else ""
        stale = [name for name, src in FIGURES.items()
                 if not (images / name).exists() or (images / name).read_bytes() != (RESULTS / src).read_bytes()]
        if stale:
            print(f"docs/images/{', '.join(stale)} differ from benchmarks/results: run python "
                  "benchmarks/results_page.py", file=sys.stderr)
            return 1
        if old != text:
            sys.stdout.writelines(difflib.unified_diff(old.splitlines(True), text.splitlines(True), "docs/results.md",
                                                       "generated", n=1))
            print("docs/results.md is stale: run python benchmarks/results_page.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text)
    for name, src in FIGURES.items():
        (images / name).write_bytes((RESULTS / src).read_bytes())
    print(f"wrote {PAGE.relative_to(ROOT)} ({len(text.splitlines())} lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
