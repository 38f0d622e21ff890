"""Do the tracker and the mapper slow each other, and is it the process they share? (issue 21)

Maps the first ``--warm`` frames at a preset (``profile_slam.warm_calls``), then times whole tracking calls (wall
clock, one torch thread; ``--timed mapping``: whole mapping calls, the other side of the pair) three ways,
interleaved over ``--repeats`` rounds:

* ``alone``: nothing else running;
* ``beside a ... thread``: a second thread of this process runs the other kind of call back to back on its own copy
  of the warmed map, as the loop's parallel mode does (the two share Python's global interpreter lock);
* ``beside a ... process``: a separate process (its own interpreter, its own copy of the same warmed map) runs the
  other kind of call back to back, as a mapper in its own process would beside the tracker.

If the thread slows the timed call much more than the process does, the lock is what the loop's two threads contend
for; if both slow it alike, it is the hardware (caches, memory bandwidth). Writes JSON with every call's time.

    python benchmarks/thread_contention.py --data ../shared/data/tum_fr1_rpy_0_124 --out benchmarks/results/thread_contention.json
    python benchmarks/thread_contention.py --timed mapping --data ../shared/data/tum_fr1_rpy_0_124 \
        --out benchmarks/results/thread_contention_mapping.json
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _warm(args):
    import torch

    from profile_slam import warm_calls

    torch.set_num_threads(1)
    return warm_calls(args["preset"], [f"data.path={args['data']}", *args["overrides"]], args["warm"])


def _other_process(args, ready, stop, count):
    """A child process: its own warmed map, calls of the kind not timed until ``stop`` is set."""
    _, track, mapping = _warm(args)
    other = track if args["timed"] == "mapping" else mapping
    other()
    ready.set()
    while not stop.is_set():
        other()
        count.value += 1


def _timed(fn, n):
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="tum/fr1_rpy-cpu")
    ap.add_argument("--data", required=True)
    ap.add_argument("--warm", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3, help="rounds of the three settings")
    ap.add_argument("--calls", type=int, default=3, help="calls timed per setting and round")
    ap.add_argument("--timed", choices=("tracking", "mapping"), default="tracking",
                    help="which call is timed; the other runs beside it")
    ap.add_argument("--out", required=True)
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args(argv)
    spec = {"preset": args.preset, "data": args.data, "warm": args.warm, "overrides": args.overrides,
            "timed": args.timed}

    from _stamp import write_timings

    _, track, _ = _warm(spec)
    _, _, mapping = _warm(spec)  # its own map: tracking freezes its scene's parameters while it runs
    track()
    mapping()
    timed, other = (mapping, track) if args.timed == "mapping" else (track, mapping)
    beside = "tracking" if args.timed == "mapping" else "mapping"
    ctx = mp.get_context("spawn")
    keys = ("alone", f"beside a {beside} thread", f"beside a {beside} process")
    times: dict[str, list[float]] = {k: [] for k in keys}
    for _ in range(args.repeats):
        times[keys[0]] += _timed(timed, args.calls)

        stop = threading.Event()

        def loop():
            while not stop.is_set():
                other()

        worker = threading.Thread(target=loop)
        worker.start()
        times[keys[1]] += _timed(timed, args.calls)
        stop.set()
        worker.join()

        ready, pstop, count = ctx.Event(), ctx.Event(), ctx.Value("i", 0)
        proc = ctx.Process(target=_other_process, args=(spec, ready, pstop, count))
        proc.start()
        ready.wait()
        times[keys[2]] += _timed(timed, args.calls)
        pstop.set()
        proc.join()
    write_timings(args.out, times, f"{args.timed} call ", preset=args.preset)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
