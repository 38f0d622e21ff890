"""Forward and forward+backward time per kind at the ESLAM and LRSLAM Replica configurations, 40k points.

    pytest benchmarks/test_field_speed.py --benchmark-enable --benchmark-json benchmarks/results/field_speed.json

Forward+backward takes gradients for both the factors (mapping) and the points (tracking).
"""

import pytest
import torch

from conftest import CONFIGS, build


@pytest.mark.parametrize("name", list(CONFIGS))
def test_forward(benchmark, name, query_points):
    field = build(name)
    benchmark.group = f"forward {name.split('/')[0]}"

    def run():
        with torch.no_grad():
            return field(query_points)

    out = benchmark(run)
    assert out.shape == (query_points.shape[0], 64)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_forward_backward(benchmark, name, query_points):
    field = build(name)
    benchmark.group = f"forward+backward {name.split('/')[0]}"

    def run():
        field.zero_grad(set_to_none=True)
        x = query_points.clone().requires_grad_(True)
        field(x).square().sum().backward()
        return x.grad

    grad = benchmark(run)
    assert torch.isfinite(grad).all()
