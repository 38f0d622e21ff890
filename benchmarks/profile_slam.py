"""Where one tracking iteration and one mapping iteration spend their time, per preset and representation.

Runs the first frames of a sequence to get a realistic map and keyframe window, then times whole tracking and
mapping calls (median of repeats) with wall-clock timers around the stages:

* fields fwd: every ``MultiResolution`` / ``Field`` query (Six-axis plane composition included);
* fields bwd: the fused kernels' backward (``tdfields.kernels``: queries, plane composition, coordinate
  transform; on the reference path it stays in "other");
* decoders fwd: the SDF and RGB MLPs;
* optimizer: ``Adam.step``;
* other: everything else (ray generation, sampling, compositing, losses, the decoders' backward, autograd).

torch.profiler was tried first and dropped: its per-op attribution here charged up to 10x the real time to some
ops (a 0.6 ms matmul showed as 11 ms), so only wall-clock timers are used. Writes JSON and a markdown table.

    python benchmarks/profile_slam.py --out benchmarks/results/profile.json --docs
    python benchmarks/profile_slam.py --presets synthetic --representations lrslam eslam
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STAGES = ["fields fwd", "fields bwd", "decoders fwd", "optimizer", "other"]


@contextlib.contextmanager
def stage_timers():
    """Patch the stage entry points with wall-clock accumulators; yields the ``{stage: seconds}`` dict."""
    import torch

    import tdfields
    from tdfields.kernels.numba import autograd as numba_autograd
    from tdfields.kernels.second_order import FirstOrderQuery

    acc: dict[str, float] = defaultdict(float)
    depth = {"n": 0}  # nested field calls (MultiResolution -> Field) count once

    def wrap(owner, name, stage, static=False):
        original = owner.__dict__[name]
        fn = original.__func__ if static else original

        def timed(*args, **kwargs):
            if depth["n"]:
                return fn(*args, **kwargs)
            depth["n"] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                acc[stage] += time.perf_counter() - t0
                depth["n"] -= 1

        setattr(owner, name, staticmethod(timed) if static else timed)
        return owner, name, original

    patches = [wrap(tdfields.MultiResolution, "forward", "fields fwd"), wrap(tdfields.Field, "forward", "fields fwd"),
               wrap(FirstOrderQuery, "backward", "fields bwd", static=True),  # NumbaProgram's (and TritonProgram's)
               wrap(numba_autograd.NumbaCompose, "backward", "fields bwd", static=True),
               wrap(numba_autograd.NumbaGridCoords, "backward", "fields bwd", static=True),
               wrap(tdfields.MLPDecoder, "forward", "decoders fwd"), wrap(torch.optim.Adam, "step", "optimizer")]
    try:
        yield acc
    finally:
        for owner, name, original in patches:
            setattr(owner, name, original)


def warm_calls(preset: str, overrides: list[str], warm_frames: int):
    """``(cfg, track, mapping)``: a SLAM that has run its first ``warm_frames`` frames, and two callables that run
    one whole tracking call (returning its :class:`TrackResult`) and one whole mapping call (returning its
    iteration count; the map restored afterwards, so every repeat maps the same map) on the next frame."""
    import torch

    from slam.config import load_config
    from slam.engine.mapper import map_frame
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.engine.tracker import track_frame

    cfg = load_config(preset, [f"data.max_frames={warm_frames + 1}", *overrides])
    ds = load_data(cfg)
    system = SLAM(cfg, ds, "cpu")
    for k in range(warm_frames):
        system.step(k)
    # parallel mode leaves the last calls running on the mapper's thread, on this very scene: finish them and stop
    # the threads, or the timed calls below race them (a torn `saved` map, and once a corrupted heap)
    system.finish()
    system.close()
    k = warm_frames
    frame = ds[system.indices[k]]
    color = torch.as_tensor(frame.color, dtype=torch.float32)
    depth = torch.as_tensor(frame.depth, dtype=torch.float32)
    init = system.state.est[-1]
    saved = {name: t.clone() for name, t in system.scene.state_dict().items()}

    def track():
        return track_frame(system.scene, color, depth, system.intr, init, cfg, system.gen)

    def mapping():
        map_frame(system.scene, k, color, depth, init, system.intr, system.keyframes, cfg, system.gen)
        system.scene.load_state_dict(saved)
        return cfg.mapping.iters

    return cfg, track, mapping


def profile_one(preset: str, representation: str, warm_frames: int, repeats: int, overrides: list[str]) -> dict:
    import torch

    cfg, track, mapping = warm_calls(preset, [f"representation={representation}", *overrides], warm_frames)
    samples = cfg.rendering.n_stratified + cfg.rendering.n_importance
    out = {"preset": preset, "representation": representation, "threads": torch.get_num_threads(),
           "tracking_points": cfg.tracking.pixels * samples, "mapping_points": cfg.mapping.pixels * samples}
    for name, fn, iters in (("tracking", track, cfg.tracking.iters), ("mapping", mapping, cfg.mapping.iters)):
        fn()  # warm-up: kernels compiled, caches filled
        runs = []
        for _ in range(repeats):
            with stage_timers() as acc:
                t0 = time.perf_counter()
                fn()
                wall = time.perf_counter() - t0
            runs.append((wall, dict(acc)))
        runs.sort(key=lambda r: r[0])
        wall, acc = runs[len(runs) // 2]
        stages = {k: 1e3 * acc.get(k, 0.0) / iters for k in STAGES[:-1]}
        stages["other"] = 1e3 * wall / iters - sum(stages.values())
        out[name] = {"per_iteration_ms": 1e3 * wall / iters, "stages_ms": {k: round(v, 2) for k, v in stages.items()}}
    return out


def table(rows: list[dict], stamp: dict) -> str:
    stages = STAGES
    lines = [f"Measured {stamp['date']} with tdfields {stamp['version']}, torch {stamp['torch']}, on {stamp['cpu']}, "
             f"{rows[0]['threads'] if rows else '?'} thread(s), kernel backend {stamp['backend']}.", "",
             "| preset | representation | phase | points / iter | ms / iter | " + " | ".join(stages) + " |",
             "|---|---|---|---|---|" + "---|" * len(stages)]
    for r in rows:
        for phase in ("tracking", "mapping"):
            p = r[phase]
            cells = [f"{p['stages_ms'].get(s, 0.0):.1f} ({100 * p['stages_ms'].get(s, 0.0) / p['per_iteration_ms']:.0f} %)"
                     for s in stages]
            points = r["tracking_points" if phase == "tracking" else "mapping_points"]
            lines.append(f"| {r['preset']} | {r['representation']} | {phase} | {points:,} | "
                         f"{p['per_iteration_ms']:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", nargs="+",
                    default=["synthetic", f"tum/fr1_rpy-cpu={ROOT.parent / 'shared' / 'data' / 'tum_fr1_rpy'}",
                             "replica/room0=synthetic"],
                    help="PRESET or PRESET=DATA_PATH; DATA_PATH 'synthetic' is the bundled sequence (default: "
                         "synthetic, the TUM excerpt, and room0's configuration on the synthetic frames)")
    ap.add_argument("--first-iters", type=int, default=100,
                    help="first-frame warm-up iterations (default 100; it only shapes the map the profile starts "
                         "from, and room0's 1000 at 160k points would take minutes)")
    ap.add_argument("--representations", nargs="+", default=["lrslam", "eslam"])
    ap.add_argument("--warm-frames", type=int, default=8, help="frames run before profiling (default 8)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "profile.json")
    ap.add_argument("--docs", action="store_true", help="write the table into docs/benchmarks.md")
    ap.add_argument("overrides", nargs="*", metavar="key=value")
    args = ap.parse_args(argv)

    import torch

    import tdfields
    from slam.engine.runtime import cpu_name
    from tdfields import kernels

    rows = []
    for item in args.presets:
        preset, _, data = item.partition("=")
        if data == "synthetic":
            from slam.data.synthetic import default_sequence

            data = str(default_sequence())
        if data and not Path(data).exists():
            print(f"skip {preset}: data not found at {data}", file=sys.stderr)
            continue
        for rep in args.representations:
            over = [f"mapping.iters_first={args.first_iters}", *args.overrides] + ([f"data.path={data}"] if data else [])
            rows.append(profile_one(preset, rep, args.warm_frames, args.repeats, over))
            print(json.dumps(rows[-1]), file=sys.stderr)
    stamp = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "version": tdfields.__version__,
             "torch": torch.__version__, "cpu": cpu_name(), "backend": kernels.get_backend()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"stamp": stamp, "rows": rows}, indent=2))
    text = table(rows, stamp)
    print(text)
    if args.docs:
        from _stamp import write_block

        write_block(ROOT / "docs" / "benchmarks.md", "profile", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
