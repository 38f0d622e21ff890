"""Loop closure in a run: its outputs (the corrected and the odometry trajectory, the summary, frames.csv's column)
and a resumed run that gives the uninterrupted run's loops and trajectories, byte for byte."""

import csv
import json

import numpy as np
import pytest
import torch

import tdfields

pytest.importorskip("cv2")
pytest.importorskip("gtsam")

from tests.slam.conftest import TINY  # noqa: E402

LOOPS = ["loops.enabled=true", "loops.keyframe_distance=0.02", "loops.keyframe_angle=1", "loops.min_gap_frames=6",
         "loops.vocabulary_after=2", "loops.words=8", "loops.refine_iters=20", "data.max_frames=16"]


def test_a_run_with_loops_writes_both_trajectories_and_resumes_to_the_same(tiny_seq, tmp_path):
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, run_to_folder

    cfg = load_config("synthetic", [*TINY, *LOOPS, f"data.path={tiny_seq}"])
    whole = run_to_folder(cfg, tmp_path / "whole", progress=False, mesh=False)
    assert whole["loops"]["keyframes"] >= 5 and whole["loops"]["loops"] >= 3  # the tiny room's camera comes back
    assert whole["loops"]["candidates_tried"] == whole["loops"]["loops"] + sum(whole["loops"]["rejected"].values())
    assert "ate_odometry_rmse_m" in whole
    # every loop carries its relative pose, and against the room's ground truth no loop is false
    assert all(len(lp["relative_pose"]) == 4 and "gt_error_m" in lp for lp in whole["loops"]["accepted"])
    assert whole["loops"]["gt_error_max_m"] < 0.05 and whole["loops"]["gt_error_max_deg"] < 2.0, whole["loops"]
    for name in ("trajectory.txt", "trajectory_odometry.txt"):
        assert len((tmp_path / "whole" / name).read_text().splitlines()) >= 16
    rows = list(csv.DictReader((tmp_path / "whole" / "frames.csv").open()))
    closed = {int(r["frame"]): int(r["loop_with"]) for r in rows if r["loop_with"]}
    assert closed and closed == {e["frame"]: e["with_frame"] for e in whole["events"] if e["event"] == "loop closed"}

    # the map follows the corrected poses: the keyframes moved, the fields re-fitted, the checkpoint in that frame
    refined = whole["map_refined"]
    assert refined["steps"] == 20 and refined["keyframe_move_max_m"] > 0 and refined["keyframes"] >= 5
    saved = tdfields.load(tmp_path / "whole" / "checkpoint.pt")
    corrected = np.loadtxt(tmp_path / "whole" / "trajectory.txt")[:, 1:4]
    np.testing.assert_allclose(saved["extra"]["poses"][:, :3, 3].numpy(), corrected, atol=1e-4)

    with pytest.raises(RunInterrupted):
        run_to_folder(cfg, tmp_path / "resumed", progress=False, mesh=False, stop_after=9)
    resumed = run_to_folder(cfg, tmp_path / "resumed", progress=False, mesh=False, resume=True)
    for name in ("trajectory.txt", "trajectory_odometry.txt"):
        assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "resumed" / name).read_bytes()
    assert json.dumps(resumed["loops"], sort_keys=True) == json.dumps(whole["loops"], sort_keys=True)
    again = tdfields.load(tmp_path / "resumed" / "checkpoint.pt")  # the refined map too, bit for bit
    assert all(torch.equal(t, again["state_dict"][name]) for name, t in saved["state_dict"].items())
    assert torch.equal(saved["extra"]["keyframe_poses"], again["extra"]["keyframe_poses"])
    # a finished run resumed again: refined once, its loops' events once
    again_m = run_to_folder(cfg, tmp_path / "resumed", progress=False, mesh=False, resume=True)
    assert [e for e in again_m["events"] if e["event"] == "loop closed"] == [
        e for e in whole["events"] if e["event"] == "loop closed"]
    twice = tdfields.load(tmp_path / "resumed" / "checkpoint.pt")
    assert all(torch.equal(t, twice["state_dict"][name]) for name, t in saved["state_dict"].items())
    assert torch.equal(saved["extra"]["keyframe_poses"], twice["extra"]["keyframe_poses"])


def test_a_checkpoint_without_loops_is_not_resumed_with_them(tiny_seq, tmp_path):
    from slam.config import load_config
    from slam.errors import SlamInputError
    from slam.run.runner import RunInterrupted, run_to_folder

    cfg = load_config("synthetic", [*TINY, "data.max_frames=8", f"data.path={tiny_seq}"])
    with pytest.raises(RunInterrupted):
        run_to_folder(cfg, tmp_path, progress=False, mesh=False, stop_after=4)
    with_loops = load_config("synthetic", [*TINY, "data.max_frames=8", f"data.path={tiny_seq}", "loops.enabled=true"])
    with pytest.raises(SlamInputError, match="loops.enabled: False vs True"):
        run_to_folder(with_loops, tmp_path, progress=False, mesh=False, resume=True)
