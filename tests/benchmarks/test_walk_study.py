"""benchmarks/walk_study.py's bookkeeping, with its SLAM runs replaced by records (a whole walk run takes half an
hour): ``--continue`` keeps what a stopped or finished sitting ran and runs only the missing (config, seed) pairs,
refuses a partial file of another length, and the curves of seed 0 come from the records, not the run folders."""

import json
import sys
from pathlib import Path

import pytest
import torch

from tests.benchmarks.conftest import load_script, script_on_path
from tests.slam.conftest import tiny_seq  # noqa: F401 - the tiny room, a fixture

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "walk_study.py"


@pytest.fixture
def study(monkeypatch):
    module = load_script("walk_study")
    calls = []

    def fake_run(name, seed, frames, mesh_resolution, out):
        calls.append((name, seed))
        if len(calls) == fake_run.fail_at:
            raise KeyboardInterrupt  # the sitting ends within a run
        return {"config": name, "seed": seed, "frames": frames, "folder": f"runs/{name}_s{seed}", "wall_s": 1.0,
                "ate_rmse_cm": 2.0 + seed, "accuracy_cm": 1.0, "completion_cm": 1.0, "completion_ratio_pct": 90.0,
                "fpt_s": 0.5, "growths": 3, "events": 3, "parameters": 100 + seed}

    fake_run.fail_at = 0
    monkeypatch.setattr(module, "run", fake_run)
    # seed 0's per-frame curve: what series() would read from that run's folder
    monkeypatch.setattr(module, "series", lambda out, folder: [{"frame": 0, "metres": 0.0, "parameters": 100,
                                                                "field_bytes": 400, "from": folder}])
    monkeypatch.setattr(module, "plot", lambda curves, path: None)
    sys.path.insert(0, str(SCRIPT.parent))
    threads = torch.get_num_threads()  # main() sets one thread for its runs
    yield module, calls, fake_run
    torch.set_num_threads(threads)
    sys.path.remove(str(SCRIPT.parent))


def test_continue_runs_only_what_is_missing(study, tmp_path, monkeypatch):
    module, calls, fake_run = study
    args = ["--frames", "20", "--seeds", "2", "--configs", "lrslam", "eslam", "--out", str(tmp_path)]
    fake_run.fail_at = 3  # lrslam s0, eslam s0 finish; lrslam s1 is cut
    with pytest.raises(KeyboardInterrupt):
        module.main(args)
    partial = json.loads((tmp_path / "walk_study.partial.json").read_text())
    assert [(r["config"], r["seed"]) for r in partial] == [("lrslam", 0), ("eslam", 0)]
    assert partial[0]["series"][0]["from"] == "runs/lrslam_s0"

    calls.clear()
    fake_run.fail_at = 0
    monkeypatch.setattr(module, "series", lambda out, folder: pytest.fail("seed 0's curve must come from its record"))
    assert module.main(args + ["--continue"]) == 0
    assert calls == [("lrslam", 1), ("eslam", 1)]
    result = json.loads((tmp_path / "walk_study.json").read_text())
    assert [(r["config"], r["seed"]) for r in result["runs"]] == [("lrslam", 0), ("eslam", 0), ("lrslam", 1),
                                                                   ("eslam", 1)]
    assert all("series" not in r for r in result["runs"])
    ate = {s["config"]: s["ate_rmse_cm"]["values"] for s in result["summary"]}
    assert ate == {"lrslam": [2.0, 3.0], "eslam": [2.0, 3.0]}
    assert result["series"]["eslam"][0]["from"] == "runs/eslam_s0"
    # a finished sitting keeps its runs for the next one: one more seed runs only that seed
    calls.clear()
    assert module.main(["--frames", "20", "--seeds", "3", "--configs", "lrslam", "--out", str(tmp_path),
                        "--continue"]) == 0
    assert calls == [("lrslam", 2)]
    assert len(json.loads((tmp_path / "walk_study.json").read_text())["runs"]) == 5


def test_continue_refuses_another_length(study, tmp_path):
    module, calls, fake_run = study
    (tmp_path / "walk_study.partial.json").write_text(json.dumps([{"config": "lrslam", "seed": 0, "frames": 300}]))
    with pytest.raises(SystemExit, match="runs of \\[300\\] frames, not --frames 20"):
        module.main(["--frames", "20", "--seeds", "1", "--configs", "lrslam", "--continue", "--out", str(tmp_path)])
    assert calls == []


def test_the_loop_oracle_and_the_refinement_study_on_a_run_with_loops(tiny_seq, tmp_path):
    # a tiny run whose camera comes back (tests/slam/loop/test_run_loops.py's settings): re-solved as the run did it,
    # the oracle must give the run's own two ATEs; with exact loops the loops' ground-truth errors are what the run
    # measured, and the graph still solves
    pytest.importorskip("cv2")
    pytest.importorskip("gtsam")
    from slam.config import load_config
    from slam.run.runner import run_to_folder
    from tests.slam.conftest import TINY
    from tests.slam.loop.test_run_loops import LOOPS

    # written without the global refinement, as the walk's runs before it existed: the refinement study below
    cfg = load_config("synthetic", [*TINY, *LOOPS, f"data.path={tiny_seq}", "loops.refine_iters=0"])
    m = run_to_folder(cfg, tmp_path / "runs" / "lrslam_loops_s0", progress=False, mesh=False)
    assert m["loops"]["loops"] >= 3
    (tmp_path / "walk_study.json").write_text(json.dumps({"runs": [
        {"config": "lrslam, loops", "seed": 0, "folder": "runs/lrslam_loops_s0", "loops": m["loops"]["loops"]},
        {"config": "lrslam", "seed": 0, "folder": "runs/none", "loops": None}]}))
    with script_on_path("walk_study") as module:
        result = module.oracle_study(tmp_path)
    (row,) = result["runs"]
    assert row["ate_cm"]["tracker"] == round(m["ate_odometry_rmse_m"] * 100, 3)
    assert row["ate_cm"]["measured loops"] == round(m["ate_rmse_m"] * 100, 3)
    assert 0 < row["ate_cm"]["exact loops"] < 5.0
    measured = sorted(round(lp["gt_error_m"] * 100, 3) for lp in m["loops"]["accepted"])
    assert sorted(row["loop_gt_error_cm"]) == pytest.approx(measured, abs=6e-3)  # the run rounds them to 0.1 mm
    written = json.loads((tmp_path / "loop_oracle.json").read_text())
    assert written["mean_std_cm"]["tracker"][0] == row["ate_cm"]["tracker"]

    # the end of the run again with the global refinement: on the corrected poses the keyframes move, on the
    # tracker's (the control) they stay; both meshes are measured against the room's
    with script_on_path("walk_study") as module:
        study = module.refine_study(tmp_path, 10)
    own, corrected, tracker = study["runs"]
    assert own["poses"].startswith("none") and own["accuracy_cm"] is None  # this run wrote no mesh
    assert corrected["refined"]["steps"] == 10 and corrected["refined"]["keyframe_move_max_m"] > 0
    assert tracker["refined"]["steps"] == 10 and tracker["refined"]["keyframe_move_max_m"] == 0
    for row in (corrected, tracker):
        assert 0 < row["accuracy_cm"] < 10 and 0 < row["completion_ratio_pct"] <= 100
    assert set(json.loads((tmp_path / "refine.json").read_text())["mean_std"]) == {own["poses"], "corrected", "tracker"}


def test_the_offline_studies_name_the_run_files_they_miss(tmp_path):
    (tmp_path / "walk_study.json").write_text(json.dumps({"runs": [
        {"config": "lrslam, loops", "seed": 0, "folder": "runs/gone_s0", "loops": 3}]}))
    with script_on_path("walk_study") as module:
        with pytest.raises(SystemExit, match="gone_s0: no config.yaml, checkpoint.pt, .*frames.csv: the study reads"):
            module.oracle_study(tmp_path)
        with pytest.raises(SystemExit, match="gone_s0: no metrics.json"):
            module.refine_study(tmp_path, 10)
