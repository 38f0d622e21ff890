"""Time and minor page faults of warm tracking and mapping calls, on a worker thread as the loop's parallel mode
runs them, for any checkout, interleaved (issue 21; docs/benchmarks.md, "The allocator fix").

Each variant is a checkout plus preset overrides; every repeat runs every variant once, in turn, each in a fresh
process with one torch thread. The child maps the first ``--warm`` frames (``profile_slam.warm_calls``, the map
restored after every mapping call), then runs ``--calls`` mapping and then tracking calls on one worker thread
after one untimed call each, and reports per call the wall time and the thread's minor page faults (``getrusage``
``RUSAGE_THREAD``): a warm call whose allocator reuses its freed memory faults almost never.

``--beside`` also times every variant next to a neighbour process on the other core, started after the warm-up
and stopped after the timed calls: ``memory`` streams two 256 MiB float32 arrays into each other (main-memory
bandwidth, as the other worker of the loop or another tenant uses it), ``compute`` multiplies a 128 x 128 matrix
that stays in its core's cache. A call that slows beside ``memory`` but not beside ``compute`` is bound by memory
traffic, not by the core.

    python benchmarks/call_faults.py --data ../shared/data/tum_fr1_rpy_0_124 --out benchmarks/results/call_beside \\
        --variant "now=.:" --beside none compute memory

    git worktree add /tmp/before e326085
    python benchmarks/call_faults.py --data ../shared/data/tum_fr1_rpy_0_124 --out benchmarks/results/call_faults \\
        --variant "e326085=/tmp/before:" --variant "now=.:"

Writes ``call_faults.json`` (every call) and ``call_faults.md`` (medians per variant over all repeats).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from before_after import parse_variant, save_variant_runs  # noqa: E402

CHILD = r"""
import concurrent.futures, json, resource, sys, time
sys.path.insert(0, {checkout!r}); sys.path.insert(0, {checkout!r} + "/benchmarks")
import torch
torch.set_num_threads(1)
from profile_slam import warm_calls
_, track, mapping = warm_calls({preset!r}, {overrides!r}, {warm!r})
import subprocess
NEIGHBOUR = {{"memory": "import numpy as np\na = np.ones(64 << 20, np.float32); b = np.empty_like(a)\n"
                       "while True:\n    np.copyto(b, a); np.copyto(a, b)",
             "compute": "import numpy as np\na = np.random.rand(128, 128).astype(np.float32)\n"
                        "while True:\n    a = (a @ a) * 0.001 + 0.5"}}
hog = subprocess.Popen([sys.executable, "-c", NEIGHBOUR[{beside!r}]]) if {beside!r} != "none" else None
time.sleep(1.0 if hog else 0.0)
def timed(fn):
    f0 = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - f0
pool = concurrent.futures.ThreadPoolExecutor(1)
out = {{}}
for name, fn in (("mapping", mapping), ("tracking", track)):
    pool.submit(timed, fn).result()
    out[name] = [pool.submit(timed, fn).result() for _ in range({calls!r})]
if hog:
    hog.kill()
    hog.wait()
json.dump(out, open({out!r}, "w"))
"""


def label(v: dict, beside: str) -> str:
    """A variant's name in the outputs: its own, or with the neighbour it ran beside."""
    return v["name"] if beside == "none" else f"{v['name']}, beside {beside}"


def run_variant(v: dict, args, path: Path, beside: str) -> dict:
    overrides = [f"data.path={Path(args.data).resolve()}", *v["args"]]
    code = CHILD.format(checkout=v["checkout"], preset=args.preset, overrides=overrides, warm=args.warm,
                        calls=args.calls, out=str(path), beside=beside)
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               PYTHONPATH=v["checkout"])
    p = subprocess.run([sys.executable, "-c", code], cwd=v["checkout"], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"call_faults: {v['name']} failed:\n{p.stderr[-3000:]}")
    return json.loads(path.read_text())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", action="append", required=True, help="NAME=CHECKOUT:OVERRIDES (repeat the option)")
    ap.add_argument("--preset", default="tum/fr1_rpy-cpu-fast")
    ap.add_argument("--data", required=True)
    ap.add_argument("--warm", type=int, default=8, help="frames run before the timed calls")
    ap.add_argument("--calls", type=int, default=6, help="timed calls of each kind per run")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--beside", nargs="+", choices=("none", "compute", "memory"), default=["none"],
                    help="run every variant alone (none) and/or next to a neighbour process (see above)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    variants = [parse_variant(v) for v in args.variant]
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for rep in range(args.repeats):
        for v in variants:
            for b in args.beside:
                name = label(v, b)
                calls = run_variant(v, args, args.out / "child.json", b)
                runs.append({"variant": name, "beside": b, "repeat": rep, "calls": calls})
                print(f"{name:24s} r{rep}: " + ", ".join(
                    f"{k} {statistics.median(c[0] for c in cs) * 1000:.0f} ms / "
                    f"{statistics.median(c[1] for c in cs):.0f} faults" for k, cs in calls.items()), flush=True)
    (args.out / "child.json").unlink(missing_ok=True)
    lines = ["| variant | mapping call | its minor faults | tracking call | its minor faults |",
             "|---|---|---|---|---|"]
    for name in (label(v, b) for v in variants for b in args.beside):
        cs = {k: [c for r in runs if r["variant"] == name for c in r["calls"][k]] for k in ("mapping", "tracking")}
        med = {k: (statistics.median(c[0] for c in cs[k]), statistics.median(c[1] for c in cs[k])) for k in cs}
        lines.append(f"| {name} | {med['mapping'][0] * 1000:.0f} ms | {med['mapping'][1]:.0f} | "
                     f"{med['tracking'][0] * 1000:.0f} ms | {med['tracking'][1]:.0f} |")
    save_variant_runs(args.out, "call_faults", variants, runs, "\n".join(lines), preset=args.preset)
    return 0


if __name__ == "__main__":
    sys.exit(main())
