"""Forward and forward+backward time per kind at the ESLAM and LRSLAM Replica configurations, 40k points.

    pytest benchmarks/test_field_speed.py --benchmark-enable --benchmark-json benchmarks/results/field_speed.json

Forward+backward takes gradients for both the factors (mapping) and the points (tracking). Every tdfields kind
runs with the fused kernels ("fused") and with the pure-PyTorch reference ("reference"); ESLAM's grid_sample
tri-plane is the baseline the speed targets are stated against. Threads: torch's setting (``--threads`` below).

With a CUDA device the same cases also run on it ("cuda-reference", "cuda-triton" when triton imports,
"cuda-torch" for grid_sample), each timed to a ``torch.cuda.synchronize()``, so one command gives the GPU
comparison the CPU numbers are published beside.
"""

import importlib.util

import pytest
import torch

import tdfields

from conftest import CONFIGS, GRID_SAMPLE, build, points
from tdfields import kernels

CASES = [(name, backend) for name in CONFIGS for backend in ("fused", "reference")
         if not (name.endswith("-factors") and backend == "reference")]  # 7 s per call: not worth a benchmark
CASES += [(name, "torch") for name in GRID_SAMPLE]
BACKEND = {"fused": "auto", "reference": "torch", "torch": "torch", "cuda-reference": "torch",
           "cuda-triton": "triton", "cuda-torch": "torch"}
if torch.cuda.is_available():
    gpu = ["cuda-reference"] + (["cuda-triton"] if importlib.util.find_spec("triton") else [])
    CASES += [(name, backend) for name in CONFIGS for backend in gpu]
    CASES += [(name, "cuda-torch") for name in GRID_SAMPLE]


def _device(backend):
    return "cuda" if backend.startswith("cuda") else "cpu"


def _sync(device):
    if device == "cuda":
        torch.cuda.synchronize()


def _id(case):
    return f"{case[0]}:{case[1]}"


def _setup(case, query_points):
    """``(field, points, device)`` for a case: CPU cases share the module's points, CUDA ones get a copy there."""
    name, backend = case
    device = _device(backend)
    return build(name, device), query_points if device == "cpu" else points(device), device


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_forward(benchmark, case, query_points):
    name, backend = case
    field, x, device = _setup(case, query_points)
    benchmark.group = f"forward {name.split('/')[0]}"

    def run():
        with torch.no_grad(), kernels.use_backend(BACKEND[backend]):
            out = field(x)
        _sync(device)
        return out

    with tdfields.frozen(field):  # a frozen map, as in SLAM tracking and meshing: Six-axis may cache its planes
        out = benchmark(run)
    assert out.shape == (x.shape[0], 64)


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_forward_backward(benchmark, case, query_points):
    name, backend = case
    field, base, device = _setup(case, query_points)
    benchmark.group = f"forward+backward {name.split('/')[0]}"

    def run():
        field.zero_grad(set_to_none=True)
        x = base.clone().requires_grad_(True)
        with kernels.use_backend(BACKEND[backend]):
            field(x).square().sum().backward()
        _sync(device)
        return x.grad

    grad = benchmark(run)
    assert torch.isfinite(grad).all()
