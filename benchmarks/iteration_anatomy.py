"""What one mapping iteration of a preset is made of: wall time per stage, torch ops and autograd nodes (issue 21).

Runs the first ``--warm-frames`` frames of a sequence inline (``benchmarks/profile_slam.py``'s ``warm_calls``), then
times ``--calls`` whole mapping calls on the next frame (the map restored after each) with wall-clock timers around
the loop's stages, counts the ATen ops one call dispatches (``torch.profiler``, counts only: its per-op times are
not trusted here, see ``profile_slam.py``) and walks the autograd graph of one iteration's loss. The point: how much
of an iteration is arithmetic and how much is the machinery around it, which decides whether a fused per-ray kernel
(issue 21's first lever) or more trimming pays.

    python benchmarks/iteration_anatomy.py --data ../shared/data/tum_fr1_rpy_0_124 \\
        --out benchmarks/results/iteration_anatomy

Writes ``iteration_anatomy.json`` and ``iteration_anatomy.md``. Below Python (torch's C++ dispatch, numba's
kernels, MKL): ``--spin 40`` keeps calling after the measurement (the PID printed) so a native sampler can attach,

    py-spy record --native -r 400 -d 15 -p PID -f raw -o native.txt

and ``--native native.txt`` (another run) sorts that file's samples by their innermost frame into numba's compiled
code, MKL, torch's C++ and Python (:func:`native_shares`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

# (module, attribute, stage): the stages timed, outermost first; nested ones are counted inside their parents too
STAGES = [("slam.engine.mapper", "render_pixels", "render (forward)"),
          ("slam.core.rendering", "_sample_ray_depths", "render: sample depths"),
          ("slam.model.scene", "SceneModel.sdf", "render: SDF field + decoder"),
          ("slam.core.fused_render", "composite", "render: compositing"),
          ("slam.core.rendering", "sample_colors", "render: colour field + decoder"),
          ("slam.engine.mapper", "pose_to_matrix", "window poses to matrices"),
          ("slam.engine.mapper", "total_loss", "losses"),
          ("torch", "Tensor.backward", "backward (all of it)"),
          ("slam.engine.mapper", "finite_step", "finite check"),
          ("slam.engine.mapper", "_Optimiser.step", "Adam step")]


def _wrap(acc: dict, module: str, attr: str, label: str):
    """Patch ``module.attr`` (``Class.method`` allowed) with a timer adding to ``acc[label]``; returns an undo."""
    import importlib

    owner = importlib.import_module(module)
    *path, name = attr.split(".")
    for p in path:
        owner = getattr(owner, p)
    original = owner.__dict__[name] if path else getattr(owner, name)

    def timed(*a, **k):
        t0 = time.perf_counter()
        try:
            return original(*a, **k)
        finally:
            acc[label] += time.perf_counter() - t0

    setattr(owner, name, timed)
    return lambda: setattr(owner, name, original)


def _graph_nodes(loss) -> Counter:
    seen, todo, kinds = set(), [loss.grad_fn], Counter()
    while todo:
        f = todo.pop()
        if f is None or f in seen:
            continue
        seen.add(f)
        kinds[type(f).__name__] += 1
        todo.extend(nf for nf, _ in f.next_functions)
    return kinds


def anatomy(preset: str, data: str, warm_frames: int, calls: int, overrides: list[str], spin: float = 0) -> dict:
    import torch

    import slam.engine.mapper as mapper
    from profile_slam import warm_calls

    cfg, _, mapping = warm_calls(preset, [f"data.path={data}", "mapper_process=false", "parallel=false", *overrides],
                                 warm_frames)
    iters = cfg.mapping.iters
    mapping()
    mapping()  # kernels compiled, caches and the allocator's pools warm
    walls, acc = [], defaultdict(float)
    undo = [_wrap(acc, *s) for s in STAGES]
    try:
        for _ in range(calls):
            t0 = time.perf_counter()
            mapping()
            walls.append(time.perf_counter() - t0)
    finally:
        for u in undo:
            u()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        mapping()
    ops = Counter({e.key: e.count for e in prof.key_averages() if e.key.startswith("aten::")})
    losses = []
    original = mapper.total_loss
    mapper.total_loss = lambda *a, **k: losses.append(original(*a, **k)) or losses[-1]
    try:
        mapping()
    finally:
        mapper.total_loss = original
    nodes = _graph_nodes(losses[-1][0])
    if spin > 0:
        import os

        print(f"iteration_anatomy: calling for {spin:.0f} s more, PID {os.getpid()}", file=sys.stderr, flush=True)
        end = time.perf_counter() + spin
        while time.perf_counter() < end:
            mapping()
    per_iter_ms = 1e3 * statistics.median(walls) / iters
    return {"preset": preset, "data": Path(data).name, "iters_per_call": iters, "calls_timed": calls,
            "per_iteration_ms": per_iter_ms,
            "stages_ms": {label: 1e3 * acc[label] / (calls * iters) for _, _, label in STAGES},
            "aten_ops_per_iteration": sum(ops.values()) / iters,
            "top_aten_ops_per_iteration": {k: v / iters for k, v in ops.most_common(12)},
            "autograd_nodes": sum(nodes.values()), "autograd_node_kinds": dict(nodes.most_common()),
            "python_backward_nodes": sum(v for k, v in nodes.items() if not k.endswith(("Backward0", "Backward1"))
                                         and k != "AccumulateGrad")}


def native_shares(raw: Path) -> dict:
    """Shares of a ``py-spy record --native -f raw`` file's (gzipped or not) samples by innermost frame: numba's
    compiled kernels (frames without a symbol, ``0x...``), MKL (``mkl_*``), torch's C++ (``::`` in the name,
    ``THP*``, ``at_*``), the C library's allocator, and the rest (Python functions and the interpreter)."""
    import gzip

    text = gzip.decompress(raw.read_bytes()).decode() if raw.suffix == ".gz" else raw.read_text()
    kinds, total = Counter(), 0
    for line in text.splitlines():
        if not line.strip():
            continue
        stack, n = line.rsplit(" ", 1)
        leaf = stack.split(";")[-1].split(" (")[0]
        if leaf.startswith("0x"):
            kind = "numba kernels"
        elif "mkl" in leaf:
            kind = "MKL"
        elif "::" in leaf or leaf.startswith(("THP", "at_", "torch")):
            kind = "torch C++"
        elif leaf in ("malloc", "free", "__tls_get_addr") or leaf.startswith("_int_"):
            kind = "C library"
        else:
            kind = "Python"
        kinds[kind] += int(n)
        total += int(n)
    return {k: v / total for k, v in kinds.most_common()}


def table(r: dict, stamp: dict) -> str:
    lines = [f"Measured {stamp['date']} on {stamp['cpu']}, torch {stamp['torch']}, {stamp['threads']} thread, "
             f"`{r['preset']}` on `{r['data']}` (median of {r['calls_timed']} calls of {r['iters_per_call']} "
             f"iterations).", "",
             "| stage | ms / iteration | share |", "|---|---|---|"]
    for label, ms in r["stages_ms"].items():
        lines.append(f"| {label} | {ms:.2f} | {100 * ms / r['per_iteration_ms']:.0f} % |")
    lines.append(f"| **whole iteration** | **{r['per_iteration_ms']:.2f}** | 100 % |")
    lines += ["", f"ATen ops dispatched per iteration: {r['aten_ops_per_iteration']:.0f} (nested ones counted); "
                  f"autograd nodes in one iteration's graph: {r['autograd_nodes']} "
                  f"({r['python_backward_nodes']} of them Python `Function`s, "
                  f"{r['autograd_node_kinds'].get('AccumulateGrad', 0)} parameter leaves)."]
    if r.get("native"):
        lines += ["", "Native samples by innermost frame (`--native`): " + ", ".join(
            f"{k} {100 * v:.0f} %" for k, v in r["native"].items()) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="tum/fr1_rpy-cpu-fast")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "tum_fr1_rpy_0_124"))
    ap.add_argument("--warm-frames", type=int, default=30, help="frames run before the timed calls (default 30)")
    ap.add_argument("--calls", type=int, default=20, help="mapping calls timed (default 20)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--spin", type=float, default=0,
                    help="after measuring, keep calling for this many seconds (for a native sampler; PID printed)")
    ap.add_argument("--native", type=Path, default=None, help="a py-spy --native raw file of such a loop to sort")
    ap.add_argument("overrides", nargs="*", metavar="key=value")
    args = ap.parse_args(argv)
    import torch

    from slam.engine.runtime import cpu_name

    if not Path(args.data).is_dir():
        print(f"iteration_anatomy: error: data folder not found: {args.data}", file=sys.stderr)
        return 2
    r = anatomy(args.preset, args.data, args.warm_frames, args.calls, args.overrides, args.spin)
    if args.native is not None:
        r["native"] = native_shares(args.native)
    stamp = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "cpu": cpu_name(),
             "torch": torch.__version__, "threads": torch.get_num_threads()}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "iteration_anatomy.json").write_text(json.dumps({"stamp": stamp, **r}, indent=2))
    text = table(r, stamp)
    (args.out / "iteration_anatomy.md").write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
