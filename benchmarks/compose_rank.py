"""Six-axis plane composition by rank: the generated kernel (``tdfields.kernels.fused_compose_plane``) against the
einsum reference (``tdfields.program.compose_plane_reference``), forward + backward, 1 thread, medians of interleaved
repeats. It sets :data:`tdfields.ops.FUSED_COMPOSE_MAX_RANK`, the rank above which ``tdfields.ops.compose_plane``
uses the reference.

Usage::

    python benchmarks/compose_rank.py --out benchmarks/results/compose_rank.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def measure(sizes=(64, 128), channels=(16, 32), ranks=(4, 8, 16, 32, 64), repeats: int = 7) -> list[dict]:
    from tdfields import kernels
    from tdfields.program import compose_plane_reference

    rows = []
    for n in sizes:
        for C in channels:
            for k in ranks:
                u = torch.randn(n, k * C, requires_grad=True)
                v = torch.randn(n, k * C, requires_grad=True)
                times = {"fused": [], "reference": []}
                fns = {"fused": kernels.fused_compose_plane, "reference": compose_plane_reference}
                for fn in fns.values():  # compile and warm up
                    fn(u, v, k).sum().backward()
                for _ in range(repeats):
                    for name, fn in fns.items():
                        t0 = time.perf_counter()
                        fn(u, v, k).sum().backward()
                        times[name].append(time.perf_counter() - t0)
                f, r = statistics.median(times["fused"]), statistics.median(times["reference"])
                rows.append({"samples": n, "channels": C, "rank": k, "fused_ms": f * 1e3, "reference_ms": r * 1e3,
                             "ratio": f / r})
                print(f"n {n} C {C} rank {k:3d}: fused {f * 1e3:7.2f} ms, reference {r * 1e3:7.2f} ms, "
                      f"{f / r:5.2f}x", flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _stamp import stamp

    torch.set_num_threads(1)
    out = {"rows": measure(repeats=args.repeats), **stamp()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
