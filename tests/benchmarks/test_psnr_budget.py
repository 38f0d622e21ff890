"""benchmarks/psnr_budget.py's reading of its curves: the parameters a kind needs for a PSNR level (linear in log
parameters between the budgets around it, never extrapolated) and the ratios to the reference kind."""

import math

import pytest

from tests.benchmarks.conftest import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("psnr_budget")


def rows(kind, points):
    return [{"kind": kind, "budget": b, "seed": s, "parameters": p, "psnr": v}
            for b, p, vals in points for s, v in enumerate(vals)]


def test_means_and_levels(bench):
    data = rows("a", [(100, 100, [20.0, 22.0]), (400, 400, [24.0, 24.0]), (1600, 1600, [25.0, 25.0])])
    data += rows("b", [(100, 110, [19.0, 19.0]), (400, 390, [21.0, 21.0]), (1600, 1610, [23.0, 23.0])])
    curves = bench.curve_means(data, ["a", "b"], [100, 400, 1600])
    assert curves["a"][0]["psnr_mean"] == 21.0 and curves["a"][0]["psnr_std"] == pytest.approx(math.sqrt(2))
    # a reaches 22.5 halfway (in log parameters) between 100 and 400: 200
    assert bench.parameters_at(curves["a"], 22.5) == pytest.approx(200.0)
    assert bench.parameters_at(curves["a"], 24.0) == pytest.approx(400.0)
    assert bench.parameters_at(curves["a"], 20.0) is None  # below its first budget: not extrapolated
    assert bench.parameters_at(curves["a"], 26.0) is None  # never reached
    # b reaches 22 halfway between 390 and 1610 in log parameters: sqrt(390 * 1610)
    table = bench.levels_table(curves, [22.0], "a")
    need_a = math.exp(math.log(100) + (1 / 3) * math.log(4))  # a: 21 -> 24 between 100 and 400, 22 a third of it
    assert table[0]["parameters"]["a"] == pytest.approx(need_a)
    assert table[0]["parameters"]["b"] == pytest.approx(math.sqrt(390 * 1610))
    assert table[0]["ratio_to_reference"]["b"] == pytest.approx(math.sqrt(390 * 1610) / need_a)
    assert table[0]["ratio_to_reference"]["a"] == pytest.approx(1.0)
