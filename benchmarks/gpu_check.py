"""The prepared GPU check: one run on one CUDA device within ``--budget-s``, one JSON + markdown stamped with it.

Steps, in this order (each with its own time limit, and all under ``--budget-s``, so one slow step cannot eat the
others' time and a lease that ends early still returns what finished; the summary is rewritten after every step):

1. ``slam-*``: a short SLAM run with ``--device cuda`` in both loop modes (sequential, parallel), with the mapper in
   its own process, and with the levers of ``tum/fr1_rpy-cpu-fast`` (carried Adam moments on the device among them).
   ``preset-*``: the presets' frame time and ATE on the excerpt, seed 0: ``tum/fr1_rpy-cpu-fast`` on the device with
   the reference path and with the Triton field kernel (``TDFIELDS_BACKEND``) and on this machine's CPU, and the
   Adam preset ``tum/fr1_rpy-cpu`` on the device and the CPU (the fast preset's frame time where the paper measured).
2. ``cuda-tests``: the Triton kernels' tests compiled for the GPU (``TRITON_INTERPRET=0``): the field query's and
   the render tail's. ``render-tail``: the render tail alone, forward and backward, PyTorch ops against the Triton
   kernels on the device at the loop's batch sizes (``benchmarks/render_tail_speed.py``).
3. ``gn-tracker-every`` / ``-first``: the second-order tracker against Adam on the device
   (``benchmarks/gn_convergence.py --device``: time per evaluation / iteration, evaluations to 1 mm and 0.1 degree
   from known offsets on the synthetic room), with the normal equations' matrix at every evaluation and at a round's
   first only (``tracking.gn_hessian``).
4. ``field-speed``: the field-speed suite's CUDA cases (reference, Triton, ESLAM's grid_sample) with
   pytest-benchmark, JSON kept.
5. ``slam``: lrslam vs eslam on the TUM excerpt at the paper's TUM settings (``tum/fr1_rpy``), first
   ``--frames`` frames, through ``benchmarks/slam_compare.py``.

``--smoke`` runs the same steps end to end on the CPU at toy sizes (the bundled-style tiny synthetic sequence, a
few iterations, the CPU field-speed cases run once): CI runs it so the script cannot rot between GPU loans.

Usage (repository root)::

    bash benchmarks/gpu_check.sh --data .gpu_data/tum_fr1_rpy --out $OUT --scratch /tmp/gc --budget-s 520  # GPU
    bash benchmarks/gpu_check.sh --smoke --out /tmp/gpu_smoke                         # anywhere, CPU only
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


class Steps:
    """The check's steps, run one after another under one overall deadline (``--budget-s``): a step gets the
    smaller of its own limit and the time left, and is skipped when under 15 s is left, so a device lease that ends
    mid-check still returns every finished step's result."""

    def __init__(self, env: dict, log: Path, budget_s: float):
        self.env, self.log, self.done = env, log, []
        self.deadline = time.perf_counter() + budget_s if budget_s > 0 else float("inf")

    def run(self, name: str, cmd: list[str], limit_s: int, env: dict | None = None) -> dict:
        left = self.deadline - time.perf_counter()
        if left < 15:
            print(f"[gpu_check] {name}: skipped ({left:.0f} s of the budget left)", flush=True)
            step = {"step": name, "command": " ".join(cmd), "returncode": "skipped", "wall_s": 0.0}
            self.done.append(step)
            return step
        limit = int(min(limit_s, left))
        t0 = time.perf_counter()
        with open(self.log, "a") as fh:
            fh.write(f"\n===== {name} (limit {limit} s): {' '.join(cmd)}\n")
            fh.flush()
            try:
                p = subprocess.run(cmd, cwd=ROOT, env=env or self.env, stdout=fh, stderr=subprocess.STDOUT,
                                   timeout=limit)
                code = p.returncode
            except subprocess.TimeoutExpired:
                code = "timeout"
        wall = time.perf_counter() - t0
        print(f"[gpu_check] {name}: {'ok' if code == 0 else code} in {wall:.0f} s", flush=True)
        step = {"step": name, "command": " ".join(cmd), "returncode": code, "wall_s": round(wall, 1)}
        self.done.append(step)
        return step


def device_info(smoke: bool) -> dict:
    import torch

    info = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "torch": torch.__version__,
            "python": platform.python_version(), "smoke": smoke, "cuda": torch.cuda.is_available()}
    if torch.cuda.is_available():
        info["device"] = torch.cuda.get_device_name()
        info["cuda_runtime"] = torch.version.cuda
        try:
            info["driver"] = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                            capture_output=True, text=True, timeout=20).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            info["driver"] = None
        try:
            import triton

            info["triton"] = triton.__version__
        except ImportError:
            info["triton"] = None
    else:
        info["device"] = "cpu"
    sys.path.insert(0, str(ROOT))
    try:
        import tdfields

        info["tdfields"] = tdfields.__version__
    except ImportError:
        pass
    return info


def _git_commit() -> str | None:
    try:
        p = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10)
        return p.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def tiny_sequence(out: Path) -> Path:
    sys.path.insert(0, str(ROOT))
    from slam.data.synthetic import SynthConfig, generate

    seq = out / "tiny_synth"
    if not (seq / "traj.txt").exists():
        generate(seq, SynthConfig(frames=8, height=48, width=64, supersample=1))
    return seq


def _read_json(path: Path) -> dict | None:
    """A step's JSON, or None where it is missing or cut off (pytest-benchmark opens its file before a step that
    then runs out of time, leaving it empty)."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def summarize(info: dict, steps: list[dict], out: Path, smoke: bool, presets: list[dict] | None = None) -> dict:
    """Gather the finished steps' JSON into ``gpu_check.json`` + ``gpu_check.md`` (rewritten after every step)."""
    result = {"info": info, "steps": steps, "presets": presets or [], "gn_tracker": {}}
    for mode in ("every", "first"):
        g = _read_json(out / f"gn_{mode}.json")
        if g:
            result["gn_tracker"][mode] = {
                "gn_ms_per_evaluation": 1000 * g["gn_s_per_evaluation"],
                "adam_ms_per_iteration": 1000 * g["adam_s_per_iteration"],
                "gn_evaluations_to_1mm_0.1deg": [c["gn_evals_to_1mm_0.1deg"] for c in g["cases"]],
                "adam_iterations_to_1mm_0.1deg": [c["adam_iters_to_1mm_0.1deg"] for c in g["cases"]]}
    if sc := _read_json(out / "slam_compare.json"):
        result["slam"] = sc["summary"]
    if tail := _read_json(out / "render_tail_speed.json"):
        result["render_tail"] = [{"size": r["size"], "reference_ms": r["median_ms"]["reference"],
                                  "fused_ms": r["median_ms"]["fused"],
                                  "largest_difference": max(r["max_abs_diff"].values())} for r in tail["sizes"]]
    if fs := _read_json(out / "field_speed_cuda.json"):
        result["field_speed"] = [{"name": b["name"], "median_ms": 1000 * b["stats"]["median"]}
                                 for b in fs["benchmarks"]]
    (out / "gpu_check.json").write_text(json.dumps(result, indent=2))
    lines = [f"GPU check {info['date']} on {info['device']} (torch {info['torch']}, triton {info.get('triton')}, "
             f"tdfields {info.get('tdfields')}, commit {str(info.get('commit'))[:7]})"
             f"{' [smoke run on CPU]' if smoke else ''}", "",
             "| step | result | wall s |", "|---|---|---|"]
    lines += [f"| {s['step']} | {'ok' if s['returncode'] == 0 else s['returncode']} | {s['wall_s']} |" for s in steps]
    if result["presets"]:
        lines += ["", "| run | preset | device | backend | frames | FPT s | ATE RMSE cm | mapping calls |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['run']} | {r['preset']} | {r['device']} | {r['backend']} | {r['frames']} | {r['fpt_s']:.4f} | "
                  f"{r['ate_rmse_cm']:.2f} | {r['mapping_calls']} |" for r in result["presets"]]
    if "slam" in result:
        lines += ["", "| representation | ATE RMSE cm | FPT s |", "|---|---|---|"]
        lines += [f"| {r['representation']} | {r['ate_rmse_cm']['mean']:.2f} | {r['fpt_s']['median']:.3f} |"
                  for r in result["slam"]]
    if result["gn_tracker"]:
        lines += ["", "| tracker | ms per evaluation / iteration | to 1 mm and 0.1 degree (per case) |",
                  "|---|---|---|"]
        for mode, g in result["gn_tracker"].items():
            lines.append(f"| Levenberg-Marquardt, matrix {'every evaluation' if mode == 'every' else 'once a round'} | "
                         f"{g['gn_ms_per_evaluation']:.1f} | {g['gn_evaluations_to_1mm_0.1deg']} |")
        g = next(iter(result["gn_tracker"].values()))
        lines.append(f"| Adam | {g['adam_ms_per_iteration']:.1f} | {g['adam_iterations_to_1mm_0.1deg']} |")
    if "render_tail" in result:
        lines += ["", "| render tail, forward + backward | PyTorch ops ms | Triton ms | largest difference |",
                  "|---|---|---|---|"]
        lines += [f"| {r['size']} | {r['reference_ms']:.3f} | {r['fused_ms']:.3f} | {r['largest_difference']:.1e} |"
                  for r in result["render_tail"]]
    if "field_speed" in result:
        lines += ["", "| case | median ms |", "|---|---|"]
        lines += [f"| {b['name']} | {b['median_ms']:.3f} |" for b in result["field_speed"]]
    (out / "gpu_check.md").write_text("\n".join(lines) + "\n")
    return result


def _keep(step: dict, src: Path, dst: Path) -> None:
    """Copy a step's JSON to the top of ``--out`` (a device call returns a few files, two folders deep at most),
    only when the step ran through (a reused scratch folder may hold an earlier run's)."""
    if step["returncode"] == 0 and src.is_file():
        shutil.copy(src, dst)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="folder for gpu_check.json, gpu_check.md, the log and the steps' JSON")
    ap.add_argument("--scratch", default=None,
                    help="folder for the runs' own outputs (default: OUT/work); only the JSONs summarized are "
                         "copied to OUT")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "tum_fr1_rpy"),
                    help="the TUM fr1_rpy excerpt (copy it into the repository to take it to a GPU machine)")
    # at the paper's TUM settings 15 frames of lrslam and eslam did not finish in 250 s on an H200 (2026-12-04):
    # 200 tracking and 60 mapping iterations a frame, 1000 on the first, ~20 ms an iteration there
    ap.add_argument("--frames", type=int, default=8, help="frames of the excerpt for the SLAM step (default 8)")
    ap.add_argument("--budget-s", type=float, default=0,
                    help="overall deadline in seconds for all steps (0: none); a step past it is skipped")
    ap.add_argument("--commit", default=None,
                    help="the commit checked, for the stamp (default: git rev-parse HEAD, where .git is present)")
    ap.add_argument("--smoke", action="store_true", help="CPU, toy sizes: the whole script in about a minute")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(args.scratch) if args.scratch else out / "work"
    work.mkdir(parents=True, exist_ok=True)
    log = out / "gpu_check.log"
    log.write_text("")
    for name in ("gn_every.json", "gn_first.json", "slam_compare.json", "field_speed_cuda.json",
                 "render_tail_speed.json"):
        (out / name).unlink(missing_ok=True)  # an earlier run's, which a failed step would otherwise leave summarized
    info = device_info(args.smoke)
    info["commit"] = args.commit or _git_commit()
    if not args.smoke and not info["cuda"]:
        print("gpu_check: error: no CUDA device here; use --smoke for the CPU dry run", file=sys.stderr)
        return 2
    if not args.smoke and not Path(args.data).is_dir():
        print(f"gpu_check: error: data folder not found: {args.data}", file=sys.stderr)
        return 2
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               PYTHONUNBUFFERED="1")
    py = sys.executable
    dev = "cpu" if args.smoke else "cuda"
    steps = Steps(env, log, args.budget_s)
    preset_rows: list[dict] = []

    def step(*a, **k):
        steps.run(*a, **k)
        summarize(info, steps.done, out, args.smoke, preset_rows)

    # ---- 1. short SLAM runs on the device, both loop modes: the first thing to know is that --device cuda runs
    seq = tiny_sequence(work)
    tiny = ["data.max_frames=6", "tracking.iters=3", "tracking.pixels=100", "mapping.iters=3", "mapping.iters_first=5",
            "mapping.pixels=200", "rendering.n_stratified=8", "rendering.n_importance=4"]
    # the third: the mapper in a child process (mapper_process), whose map lives on the device too; the fourth: the
    # levers of tum/fr1_rpy-cpu-fast (second-order tracker, matrix once a round, mapping by need, carried moments on
    # the device, the fused tail, which falls back to PyTorch ops there)
    fast = ["parallel=true", "tracking.optimizer=gauss_newton", "tracking.gn_hessian=first", "mapping.schedule=by_need",
            "mapping.need_young=2", "mapping.optimizer_state=persistent", "rendering.fused=true"]
    for mode, name, over in (("false", "parallel=false", ["parallel=false"]),
                             ("true", "parallel=true", ["parallel=true"]),
                             ("process", "parallel=process", ["parallel=true", "mapper_process=true"]),
                             ("fast", "fast-levers", fast)):
        step(f"slam-{dev}-{name}", [py, "-m", "slam.cli", "run", "--quiet", "--no-mesh", "--device", dev, "--data",
                                    str(seq), "--out", str(work / f"tiny_{mode}"), *tiny, *over], 90)
    # ---- 1b. the presets' frame time on this machine, the device against its own CPU, seed 0 (issue 21 asks how
    # fast the fast preset is where the paper measured): tum/fr1_rpy-cpu-fast on cuda with the reference path and with
    # the Triton field kernel, on the host CPU, and the Adam preset tum/fr1_rpy-cpu on cuda and on the CPU
    for name, preset, device, backend in (("fast-cuda", "tum/fr1_rpy-cpu-fast", dev, "torch"),
                                          ("fast-cuda-triton", "tum/fr1_rpy-cpu-fast", dev, "triton"),
                                          ("fast-cpu", "tum/fr1_rpy-cpu-fast", "cpu", "auto"),
                                          ("adam-cuda", "tum/fr1_rpy-cpu", dev, "torch"),
                                          ("adam-cpu", "tum/fr1_rpy-cpu", "cpu", "auto")):
        if args.smoke and name in ("fast-cuda-triton", "adam-cuda"):
            continue  # the same as fast-cpu / adam-cpu on a CPU
        preset, data, over = ("synthetic", str(seq), tiny) if args.smoke else (preset, args.data, [])
        ran = steps.run(f"preset-{name}", [py, "-m", "slam.cli", "run", "--quiet", "--no-mesh", "--config", preset,
                                           "--device", device, "--data", data, "--out", str(work / f"preset_{name}"),
                                           *over, "seed=0"], 120, dict(env, TDFIELDS_BACKEND=backend))
        if ran["returncode"] == 0 and (m := _read_json(work / f"preset_{name}" / "metrics.json")):
            preset_rows.append({"run": name, "preset": preset, "device": device, "backend": backend,
                                "frames": m["num_frames"], "fpt_s": m["fpt_s"], "ate_rmse_cm": 100 * m["ate_rmse_m"],
                                "mapping_calls": m.get("mapping_calls"), "frames_lost": m.get("frames_lost")})
        summarize(info, steps.done, out, args.smoke, preset_rows)
    # ---- 2. the Triton kernels' tests (the field query and the render tail), compiled for the GPU; then the render
    # tail alone, the PyTorch ops against the Triton kernels on the device (smoke: in Triton's interpreter)
    triton_tests = ["tests/tdfields/kernels/triton/test_autograd.py", "tests/slam/core/test_render_kernels_triton.py"]
    if args.smoke:
        step("cuda-tests", [py, "-m", "pytest", "-q", "-x", *triton_tests, "-k", "cp or triplane or reference"], 300,
             dict(env, TRITON_INTERPRET="1"))
    else:
        step("cuda-tests", [py, "-m", "pytest", "-q", *triton_tests], 150, dict(env, TRITON_INTERPRET="0"))
    ran = steps.run("render-tail", [py, "benchmarks/render_tail_speed.py", "--device", dev, "--out",
                                    str(work / "tail"), *(["--smoke"] if args.smoke else [])], 90,
                    dict(env, TDFIELDS_BACKEND="triton", TRITON_INTERPRET="1" if args.smoke else "0"))
    _keep(ran, work / "tail" / "render_tail_speed.json", out / "render_tail_speed.json")
    summarize(info, steps.done, out, args.smoke, preset_rows)
    # ---- 3. the second-order tracker against Adam on the device (smoke: 3 frames mapped, one test frame), with its
    # normal equations' matrix at every evaluation and at a round's first only (tracking.gn_hessian)
    gn = ["--frames", "3", "--test-frames", "3", "--offsets", "1.0", "--", "mapping.iters=3", "mapping.iters_first=5",
          "tracking.pixels=100"] if args.smoke else ["--"]
    for mode in ("every", "first"):
        ran = steps.run(f"gn-tracker-{mode}", [py, "benchmarks/gn_convergence.py", "--out", str(work / f"gn_{mode}"),
                                               "--device", dev, *gn, f"tracking.gn_hessian={mode}"], 120)
        _keep(ran, work / f"gn_{mode}" / "gn_convergence.json", out / f"gn_{mode}.json")
        summarize(info, steps.done, out, args.smoke, preset_rows)
    # ---- 4. field speed
    bench = [py, "-m", "pytest", "benchmarks/test_field_speed.py", "-p", "no:cacheprovider", "-q"]
    if args.smoke:
        step("field-speed", bench + ["--benchmark-disable", "-k", "lrslam-cp and fused"], 300)
    else:
        step("field-speed", bench + ["--benchmark-enable", "-k", "cuda", "--benchmark-max-time=0.2",
                                     "--benchmark-min-rounds=5", f"--benchmark-json={out / 'field_speed_cuda.json'}"],
             200)  # on an H200, 21 of its 24 cases took 120 s (2026-12-04)
    # ---- 5. lrslam vs eslam at the paper's TUM settings (smoke: the tiny sequence, synthetic preset); last, as the
    # longest step
    if args.smoke:
        sc = ["--sequences", f"synthetic={seq}", "--seeds", "1", *tiny]
    else:
        sc = ["--sequences", f"tum/fr1_rpy={args.data}", "--seeds", "1", f"data.max_frames={args.frames}"]
    ran = steps.run("slam", [py, "benchmarks/slam_compare.py", *sc[:2], "--representations", "lrslam", "eslam",
                             "--no-mesh", "--quiet", "--out", str(work / "slam"), *sc[2:], f"device={dev}"],
                    60 if args.smoke else 270)
    _keep(ran, work / "slam" / "slam_compare.json", out / "slam_compare.json")
    result = summarize(info, steps.done, out, args.smoke, preset_rows)
    print((out / "gpu_check.md").read_text(), end="")
    return 0 if all(s["returncode"] == 0 for s in result["steps"]) else 1


if __name__ == "__main__":
    sys.exit(main())
