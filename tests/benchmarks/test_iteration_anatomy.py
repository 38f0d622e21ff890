"""benchmarks/iteration_anatomy.py: its stage timers sit on the mapping call's real path (every stage is hit, and
are taken off again afterwards), its graph walk counts what one iteration builds, and the native samples are sorted
by their innermost frame."""

import gzip

import pytest

from tests.benchmarks.conftest import script_on_path
from tests.slam.conftest import TINY, tiny_seq  # noqa: F401 - the tiny synthetic sequence fixture


@pytest.fixture(scope="module")
def bench():
    with script_on_path("iteration_anatomy") as module:
        yield module


def test_every_stage_of_a_mapping_call_is_timed_and_the_graph_walked(bench, tiny_seq):
    import torch

    import slam.engine.mapper as mapper
    from slam.config import load_config
    from slam.model.scene import SceneModel

    before = mapper.render_pixels
    # the fused render tail on, as in the fast preset: its compositing is one of the stages
    over = [*TINY[1:], "mapping.every_frame=1", "rendering.fused=true"]
    r = bench.anatomy("synthetic", str(tiny_seq), 2, 2, over)
    assert mapper.render_pixels is before  # the timers are gone
    assert set(r["stages_ms"]) == {label for _, _, label in bench.STAGES}
    assert all(ms > 0 for ms in r["stages_ms"].values()), r["stages_ms"]
    # the forward's parts are inside it, and no stage outgrows the iteration
    parts = [ms for label, ms in r["stages_ms"].items() if label.startswith("render: ")]
    assert sum(parts) < r["stages_ms"]["render (forward)"] < r["per_iteration_ms"]
    assert r["iters_per_call"] == 3 and r["aten_ops_per_iteration"] > 100
    # one leaf per map parameter (no BA yet with 3 keyframes): the walk reaches the whole graph
    scene = SceneModel(load_config("synthetic", over, profile="quality"), torch.tensor([[0.0, 1.0]] * 3))
    assert r["autograd_node_kinds"]["AccumulateGrad"] == len(list(scene.parameters()))
    assert r["python_backward_nodes"] >= 3  # the fused field queries' Functions at least


def test_native_samples_are_sorted_by_their_innermost_frame(bench, tmp_path):
    raw = "\n".join(["main (a.py:1);map_frame (m.py:2);0x7f00deadbeef 6",
                     "main (a.py:1);addmm;mkl_blas_sgemm_kernel 2",
                     "main (a.py:1);at::native::add_kernel 1",
                     "main (a.py:1);map_frame (m.py:2) 1", ""])
    (tmp_path / "n.txt.gz").write_bytes(gzip.compress(raw.encode()))
    shares = bench.native_shares(tmp_path / "n.txt.gz")
    assert shares == {"numba kernels": 0.6, "MKL": 0.2, "torch C++": 0.1, "Python": 0.1}
