"""The SDF head's forward and backward as one hand-written numba pass per point, against PyTorch's modules (MKL
matmuls): issue 21's question whether the decoders belong inside a fused per-ray kernel on the CPU.

The head is LRSLAM's (``tdfields.MLPDecoder(64, 1, hidden=16, output_activation="tanh")``); the kernel computes per
point the two hidden layers, the output, and back the gradients of the input features and of every weight and
bias (the weight gradients accumulated point by point, as a per-ray kernel would have to). Checks the values and
gradients against PyTorch first, then times both on ``--points`` random features, one thread, alternated
``--repeats`` times; medians. Writes JSON.

    python benchmarks/decoder_numba.py --out benchmarks/results/decoder_numba.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _kernel():
    import numpy as np
    from numba import njit

    @njit(fastmath=True, nogil=True)
    def forward_backward(X, gout, W1t, b1, W2t, b2, w3, b3, out, gX, gW1t, gb1, gW2t, gb2, gw3, gb3):
        n_points, width = X.shape
        hidden = b1.shape[0]
        h1 = np.empty(hidden, np.float32)
        h2 = np.empty(hidden, np.float32)
        g1 = np.empty(hidden, np.float32)
        g2 = np.empty(hidden, np.float32)
        for n in range(n_points):
            for j in range(hidden):
                h1[j] = b1[j]
            for i in range(width):
                x = X[n, i]
                for j in range(hidden):
                    h1[j] += x * W1t[i, j]
            for j in range(hidden):
                h1[j] = max(h1[j], 0.0)
                h2[j] = b2[j]
            for i in range(hidden):
                x = h1[i]
                for j in range(hidden):
                    h2[j] += x * W2t[i, j]
            s = b3[0]
            for j in range(hidden):
                h2[j] = max(h2[j], 0.0)
                s += h2[j] * w3[j]
            y = np.tanh(s)
            out[n] = y
            gs = gout[n] * (1 - y * y)
            gb3[0] += gs
            for j in range(hidden):
                gw3[j] += gs * h2[j]
                g2[j] = gs * w3[j] if h2[j] > 0 else 0.0
                gb2[j] += g2[j]
            for i in range(hidden):
                x = h1[i]
                acc = 0.0
                for j in range(hidden):
                    gW2t[i, j] += x * g2[j]
                    acc += W2t[i, j] * g2[j]
                g1[i] = acc if x > 0 else 0.0
            for j in range(hidden):
                gb1[j] += g1[j]
            for i in range(width):
                x = X[n, i]
                acc = 0.0
                for j in range(hidden):
                    gW1t[i, j] += x * g1[j]
                    acc += W1t[i, j] * g1[j]
                gX[n, i] = acc

    return forward_backward


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=19200, help="points a batch (a mapping iteration at 800 x 24)")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)

    import numpy as np
    import torch

    import tdfields
    from _stamp import write_timings

    torch.set_num_threads(1)
    torch.manual_seed(0)
    head = tdfields.MLPDecoder(64, 1, hidden=16, output_activation="tanh")
    lin = [m for m in head.net if isinstance(m, torch.nn.Linear)]
    x = torch.randn(args.points, 64)
    xt = x.clone().requires_grad_()

    def torch_pass():
        xt.grad = None
        head.zero_grad()
        y = head(xt)[:, 0]
        y.sum().backward()
        return y

    params = [lin[0].weight.detach().T.contiguous().numpy(), lin[0].bias.detach().numpy(),
              lin[1].weight.detach().T.contiguous().numpy(), lin[1].bias.detach().numpy(),
              lin[2].weight.detach()[0].contiguous().numpy(), lin[2].bias.detach().numpy()]
    X, gout = x.numpy(), np.ones(args.points, np.float32)
    out, gX = np.empty(args.points, np.float32), np.empty_like(X)
    grads = [np.zeros_like(p) for p in params]
    kernel = _kernel()

    def numba_pass():
        for g in grads:
            g[:] = 0
        kernel(X, gout, params[0], params[1], params[2], params[3], params[4], params[5], out, gX, *grads)

    y = torch_pass()
    numba_pass()
    checks = {"output": np.abs(out - y.detach().numpy()).max(), "input gradient": np.abs(gX - xt.grad.numpy()).max(),
              "first weight gradient (relative)": np.abs(grads[0] - lin[0].weight.grad.T.numpy()).max()
              / np.abs(grads[0]).max()}
    for name, err in checks.items():
        if not err < 1e-4:
            raise SystemExit(f"decoder_numba: the kernel's {name} is off by {err}")
    times: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        for name, fn in (("PyTorch (MKL), forward + backward", torch_pass), ("numba per point", numba_pass)):
            t0 = time.perf_counter()
            fn()
            times.setdefault(name, []).append(time.perf_counter() - t0)
    write_timings(args.out, times, "", points=args.points, max_errors={k: float(v) for k, v in checks.items()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
