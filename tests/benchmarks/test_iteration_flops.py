"""benchmarks/iteration_flops.py counts the work of the queries the SLAM loop really runs: its counters sit on the
live call path (a query under autograd is counted forward and backward, a no-grad one forward only), and the
counts equal the closed forms of a small Six-axis field."""

import pytest
import torch

import tdfields
from tests.benchmarks.conftest import script_on_path


@pytest.fixture(scope="module")
def bench():
    with script_on_path("iteration_flops") as module:
        yield module


def test_counts_a_six_axis_query(bench):
    field = tdfields.SixAxis([[0, 1], [0, 1], [0, 1]], grid_shape=(5, 6, 7), channels=4, rank=2)
    x = torch.rand(100, 3)
    x[0], x[1] = 0.0, 1.0  # the batch spans the box: every plane is composed whole
    k, C = 2, 4
    # per point: three planes, each 4 corner rows of C values blended (2 FLOPs a value), then the rank sum (C)
    lookup = 100 * 3 * (2 * 4 * C + C)
    compose = 2 * (5 * 6 + 6 * 7 + 7 * 5) * k * C
    with bench.counting() as totals:
        field(x).sum().backward()
    assert totals["lookup_points"] == 100
    assert totals["lookup_fwd"] == lookup and totals["lookup_bwd"] == 2 * lookup
    assert totals["compose_fwd"] == compose and totals["compose_bwd"] == 2 * compose
    with bench.counting() as totals, torch.no_grad():
        field(x)
    assert totals["lookup_fwd"] == lookup and totals["lookup_bwd"] == 0 and totals["compose_bwd"] == 0
    # the patches are gone afterwards
    with torch.no_grad():
        field(x)
    assert totals["lookup_fwd"] == lookup
