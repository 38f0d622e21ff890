"""benchmarks/memory_rss.py at toy size: one run of the tiny room sampled every 2 frames, and its table row; the
meshing mode on a tiny run."""

import json

from tests.benchmarks.conftest import script_on_path
from tests.slam.conftest import tiny_seq  # noqa: F401 - the tiny room, a fixture


def test_a_run_samples_resident_memory_and_its_parts(tiny_seq, tmp_path):
    out = tmp_path / "run.json"
    with script_on_path("memory_rss") as bench:
        bench.run_one("synthetic", "after", str(tiny_seq), 4, 2, 2, str(out))
        rec = json.loads(out.read_text())
        text = bench.table([rec], {"date": "d", "tdfields_version": "v", "torch_version": "t", "cpu": "c",
                                   "torch_threads": 1, "device": "cpu"}, "toy")
    assert [p["frame"] for p in rec["series"]][:2] == [0, 2]
    last = rec["series"][-1]
    assert last["rss_mb"] >= last["base_mb"] > 0 and last["scene_mb"] > 0 and last["keyframes"] >= 1
    assert "| synthetic | after |" in text


def test_the_mesh_mode_meshes_a_run_dense_and_in_blocks(tiny_seq, tmp_path):
    """``--mesh RUN``: ``lrslam mesh`` of a tiny run, dense and in blocks, each in its own process, scored against
    the room's ground-truth mesh; one table row each."""
    from slam.config import load_config
    from slam.run.runner import run_to_folder
    from tests.slam.conftest import TINY

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "evaluation.depth_l1_views=0",
                                    "evaluation.samples=2000"], profile="quality")
    run_to_folder(cfg, tmp_path / "run", progress=False, mesh=False)
    with script_on_path("memory_rss") as bench:
        assert bench.main(["--mesh", str(tmp_path / "run"), "--resolution", "0.1", "--block-cells", "0", "8",
                           "--out", str(tmp_path / "out")]) == 0
        d = json.loads((tmp_path / "out" / "mesh_rss.json").read_text())
        text = bench.mesh_table(d)
    assert [r["block_cells"] for r in d["results"]] == [0, 8]
    for r in d["results"]:
        assert r["exit"] == 0 and r["peak_rss_mb"] > 0 and r["faces"] > 0
        assert 0 < r["reconstruction"]["accuracy_m"] < 1 and 0 <= r["reconstruction"]["completion_ratio"] <= 1
    assert "| dense |" in text and "| blocks of 8 cells |" in text
