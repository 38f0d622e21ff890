"""Whole tracking and mapping calls with the fused render tail off and on (``rendering.fused``), interleaved.

Maps the first ``--warm`` frames of a sequence at a preset (``benchmarks/profile_slam.py``'s ``warm_calls``), then
times one whole tracking call and one whole mapping call (the map restored after each) on the next frame, with
``rendering.fused`` false and true in turn, ``--repeats`` times, one torch thread. Times are the calling thread's CPU
time (``time.thread_time``; the fused kernels run on that thread), so a machine shared with other jobs still gives a
usable ratio; medians per (call, setting). Writes JSON with every repeat.

    python benchmarks/fused_tail_ab.py --data ../shared/data/tum_fr1_rpy_0_124 --out benchmarks/results/fused_tail_ab.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="tum/fr1_rpy-cpu")
    ap.add_argument("--data", required=True, help="sequence folder")
    ap.add_argument("--representation", default="lrslam")
    ap.add_argument("--warm", type=int, default=8, help="frames mapped before the timed calls")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)

    import torch

    from _stamp import write_timings
    from profile_slam import warm_calls

    torch.set_num_threads(1)
    cfg, track, mapping = warm_calls(args.preset, [f"representation={args.representation}",
                                                   f"data.path={args.data}"], args.warm)
    times: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        for fused in (False, True):
            cfg.rendering.fused = fused
            for name, fn in (("tracking", track), ("mapping", mapping)):
                t0 = time.thread_time()
                fn()
                times.setdefault(f"{name}, fused={fused}", []).append(time.thread_time() - t0)
    write_timings(args.out, times, "", preset=args.preset, representation=args.representation,
                  warm_frames=args.warm)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
