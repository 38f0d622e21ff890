"""The Six-axis sub-plane composition of a real mapping call, with and without its two shortcuts: the forward
composing only the cells the batch reads (``compose_plane``'s ``read_at``) and the backward skipping the cells
whose gradient is zero.

Maps the first ``--warm`` frames at a preset (``profile_slam.warm_calls``), records every composition of one
mapping call (the line factors, the points' plane coordinates and the plane's gradient), then times each kernel
on those inputs, one thread, the variants alternated ``--repeats`` times: the forward over every cell of the
bounding box against the read cells only, the backward as it is against the same kernel without the zero-cell
check (its source generated without those lines: the kernel before the shortcut). Checks on the way that each
pair gives the same numbers bit for bit where they must (the read cells; every gradient). Times are summed over
the call's compositions (6 a mapping iteration, 3 planes x 2 levels); medians over repeats.

    python benchmarks/compose_cells.py --data ../shared/data/tum_fr1_rpy_0_124 \\
        --out benchmarks/results/compose_cells/fast_window.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

#: the zero-cell check of compose_backward, as :func:`tdfields.kernels.numba.source.compose_source` writes it
_SKIP = """            live = False
            for c in range({C}):
                if GP[row, c] != ZERO:
                    live = True
                    break
            if not live:
                continue
"""


def _record(mapping):
    """Every composition of one mapping call: ``(u, v, rank, read_at, grad_plane)``, detached copies."""
    from tdfields.kernels.numba import autograd as numba_autograd

    cls = numba_autograd.NumbaCompose
    fwd, bwd, seen = cls.forward, cls.backward, []

    def forward(ctx, u, v, rank, read_at=None):
        seen.append([u.detach().clone(), v.detach().clone(), rank, None if read_at is None else read_at.clone()])
        ctx.index = len(seen) - 1
        return fwd(ctx, u, v, rank, read_at)

    def backward(ctx, grad):
        seen[ctx.index].append(grad.detach().contiguous().clone())
        return bwd(ctx, grad)

    cls.forward, cls.backward = staticmethod(forward), staticmethod(backward)
    try:
        mapping()
    finally:
        cls.forward, cls.backward = staticmethod(fwd), staticmethod(bwd)
    return [s for s in seen if len(s) == 5]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="tum/fr1_rpy-cpu-fast")
    ap.add_argument("--data", required=True, help="sequence folder")
    ap.add_argument("--warm", type=int, default=16, help="frames mapped before the recorded call")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)

    import numpy as np
    import torch

    from _stamp import write_timings
    from profile_slam import warm_calls
    from tdfields.kernels.cache import _module
    from tdfields.kernels.numba import source
    from tdfields.kernels.numba.autograd import _live_cells

    torch.set_num_threads(1)
    cfg, _, mapping = warm_calls(args.preset, [f"data.path={args.data}"], args.warm)
    mapping()
    calls = _record(mapping)
    rank, channels = calls[0][2], calls[0][0].shape[1] // calls[0][2]
    text = source.compose_source(rank, channels)
    before = text.replace(_SKIP.format(C=channels), "")
    if before == text:
        raise SystemExit("compose_cells: the zero-cell check was not found in the kernel source")
    now = _module(("compose-bench", "now"), lambda: text)
    old = _module(("compose-bench", "before"), lambda: before)

    def forward(u, v, live):
        plane = np.empty((u.shape[0] * v.shape[0], channels), np.float32)
        if live is None:
            now.compose_forward(u, v, plane, 0, u.shape[0])
        else:
            now.compose_forward_cells(u, v, plane, live, 0, u.shape[0])
        return plane

    def backward(mod, u, v, gp):
        gu, gv = np.empty_like(u), np.zeros_like(v)
        mod.compose_backward(u, v, gp, gu, gv, True, True, 0, u.shape[0])
        return gu, gv

    inputs, live_share = [], []
    for u, v, _, read_at, grad in calls:
        un, vn = u.numpy(), v.numpy()
        live = _live_cells(read_at, u.shape[0], v.shape[0])
        gp = grad.reshape(-1, channels).numpy()
        inputs.append((un, vn, live, gp))
        live_share.append(float(live.mean()) if live is not None else 1.0)
        full, cells = forward(un, vn, None), forward(un, vn, live)
        if live is not None and not np.array_equal(full[live == 1], cells[live == 1]):
            raise SystemExit("compose_cells: the read cells differ between the two forwards")
        for a, b in zip(backward(now, un, vn, gp), backward(old, un, vn, gp)):
            if not np.array_equal(a, b):
                raise SystemExit("compose_cells: the backward with the zero-cell check differs")
    times: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        for name, run in (("forward, every cell of the box", lambda i: forward(i[0], i[1], None)),
                          ("forward, the read cells", lambda i: forward(i[0], i[1], i[2])),
                          ("backward, every cell", lambda i: backward(old, i[0], i[1], i[3])),
                          ("backward, skipping zero cells", lambda i: backward(now, i[0], i[1], i[3]))):
            t0 = time.thread_time()
            for item in inputs:
                run(item)
            times.setdefault(name, []).append(time.thread_time() - t0)
    write_timings(args.out, times, "", preset=args.preset, warm_frames=args.warm, compositions=len(inputs),
                  read_cell_share=live_share)
    print(f"{len(inputs)} compositions a mapping call, read cells {min(live_share):.2f}-{max(live_share):.2f} "
          "of their sub-planes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
