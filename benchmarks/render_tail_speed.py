"""The render tail alone, reference against fused, forward and backward, on one device (issue 21's fused path).

Times ESLAM's compositing, the colour sum and the five loss terms with their backward, from given SDF and colour
samples to the gradients of the loss to them and to ``beta``, at the batch sizes the loop runs: the PyTorch ops of
:mod:`slam.core.rendering` / :mod:`slam.core.losses` (``TDFIELDS_BACKEND`` torch, the reference) against the fused
tail of :mod:`slam.core.fused_render` (numba's kernels on the CPU, Triton's on CUDA). Alternates the two, medians of
``--repeats`` rounds of ``--calls`` calls each (CUDA: synchronised before the clock is read), and checks on each
size that both give the same loss and gradients (the compiled Triton kernels' first check on a GPU).

    python benchmarks/render_tail_speed.py --out benchmarks/results/render_tail_speed            # this CPU
    TDFIELDS_BACKEND=triton python benchmarks/render_tail_speed.py --device cuda --out $OUT/tail  # a GPU

Writes ``render_tail_speed.json`` (every round, the stamp) and ``render_tail_speed.md``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

#: name -> (rays, samples a ray): the fast preset's tracking and mapping batches, and ESLAM's CPU budget's tracking
SIZES = {"tracking, fast preset (400 x 16)": (400, 16), "mapping, fast preset (800 x 16)": (800, 16),
         "tracking, ESLAM's CPU budget (1000 x 56)": (1000, 56)}
SMOKE_SIZES = {"smoke (100 x 12)": (100, 12)}


def _inputs(rays: int, samples: int, device: str, seed: int = 0) -> dict:
    """A batch as the loop hands it to the tail: sorted sample depths around each ray's measurement, SDF values
    crossing zero near it, colours in (0, 1), a tenth of the rays without depth."""
    import torch

    g = torch.Generator().manual_seed(seed)
    D = torch.rand(rays, generator=g) * 2 + 0.5
    z = torch.sort(D[:, None] + (torch.rand(rays, samples, generator=g) - 0.5) * 0.3, -1).values
    D[: rays // 10] = 0.0
    sdf = torch.tanh((D[:, None] - z) / 0.06 + 0.1 * torch.randn(rays, samples, generator=g))
    rgb = torch.rand(rays, samples, 3, generator=g)
    color = torch.rand(rays, 3, generator=g)
    return {k: v.to(device) for k, v in dict(z=z, D=D, sdf=sdf, rgb=rgb, color=color).items()}


def tail_step(batch: dict, fused: bool) -> tuple:
    """One forward and backward of the tail: ``(loss, d loss / d sdf, d rgb, d beta)``."""
    import torch

    from slam.config import MAPPING_WEIGHTS
    from slam.core.losses import total_loss
    from slam.core.rendering import color_sum, composite

    sdf = batch["sdf"].detach().requires_grad_()
    rgb = batch["rgb"].detach().requires_grad_()
    beta = torch.tensor(10.0, device=sdf.device, requires_grad=True)
    z = batch["z"]
    w, depth = composite(sdf, beta, z, fused)
    color = color_sum(w, rgb, fused)
    loss, _ = total_loss(sdf, z, depth, color, batch["D"], batch["color"], 0.06, MAPPING_WEIGHTS(),
                         fused=fused)
    loss.backward()
    return loss.detach(), sdf.grad, rgb.grad, beta.grad


def _timed(batch: dict, fused: bool, calls: int, sync) -> float:
    sync()
    t0 = time.perf_counter()
    for _ in range(calls):
        tail_step(batch, fused)
    sync()
    return (time.perf_counter() - t0) / calls


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu", help="cpu (numba's kernels) or cuda (Triton's, TDFIELDS_BACKEND=triton)")
    ap.add_argument("--repeats", type=int, default=7, help="rounds per size and setting, alternated (default 7)")
    ap.add_argument("--calls", type=int, default=20, help="tail steps a round (default 20)")
    ap.add_argument("--smoke", action="store_true", help="one small size, 2 rounds of 2 calls")
    ap.add_argument("--out", required=True, help="folder for render_tail_speed.json and .md")
    args = ap.parse_args(argv)

    import torch

    from _stamp import stamp, stamp_line
    from slam.core import fused_render
    from tdfields import kernels

    torch.set_num_threads(1)
    sync = torch.cuda.synchronize if args.device.startswith("cuda") else (lambda: None)
    repeats, calls = (2, 2) if args.smoke else (args.repeats, args.calls)
    rows = []
    for name, (rays, samples) in (SMOKE_SIZES if args.smoke else SIZES).items():
        batch = _inputs(rays, samples, args.device)
        if not fused_render.eligible(batch["sdf"], constant=(batch["z"],)):
            print(f"render_tail_speed: the fused tail cannot run on {args.device} with backend "
                  f"{kernels.get_backend()!r} (CUDA needs TDFIELDS_BACKEND=triton)", file=sys.stderr)
            return 2
        ref, got = tail_step(batch, False), tail_step(batch, True)  # also the warm-up (compiles the kernels)
        diff = [float((a - b).abs().max()) for a, b in zip(got, ref)]
        scale = [float(b.abs().max()) for b in ref]
        times = {"reference": [], "fused": []}
        for _ in range(repeats):
            for setting, fused in (("reference", False), ("fused", True)):
                times[setting].append(_timed(batch, fused, calls, sync))
        med = {k: statistics.median(v) for k, v in times.items()}
        rows.append({"size": name, "rays": rays, "samples": samples, "seconds": times,
                     "median_ms": {k: 1000 * v for k, v in med.items()}, "fused_over_reference": med["fused"] /
                     med["reference"], "max_abs_diff": dict(zip(("loss", "d_sdf", "d_rgb", "d_beta"), diff)),
                     "max_abs_reference": dict(zip(("loss", "d_sdf", "d_rgb", "d_beta"), scale))})
        print(f"{name}: reference {1000 * med['reference']:.3f} ms, fused {1000 * med['fused']:.3f} ms "
              f"({med['fused'] / med['reference']:.2f}x); largest difference {max(diff):.2e}", flush=True)
    info = stamp(args.device)
    info["backend"] = kernels.get_backend()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "render_tail_speed.json").write_text(json.dumps({"stamp": info, "command": sys.argv, "repeats": repeats,
                                                            "calls": calls, "sizes": rows}, indent=2))
    lines = [stamp_line(info) + f" Backend {info['backend']}; medians of {repeats} alternated rounds of {calls} calls.",
             "", "| batch | reference ms | fused ms | fused / reference | largest difference |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['size']} | {r['median_ms']['reference']:.3f} | {r['median_ms']['fused']:.3f} | "
              f"{r['fused_over_reference']:.2f}x | {max(r['max_abs_diff'].values()):.1e} |" for r in rows]
    (out / "render_tail_speed.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
