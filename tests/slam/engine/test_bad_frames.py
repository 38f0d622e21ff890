"""Bad frames are events, not aborts: a truncated PNG in a copy of the real TUM excerpt, frames without depth,
a frame 0 whose ground truth is invalid; too many bad frames stop the run after its outputs are written."""

import json
import os
from pathlib import Path

import pytest
import torch

from slam.config import load_config
from tests.slam.conftest import EditedDataset

FAST = ["data.max_frames=8", "tracking.iters=2", "tracking.pixels=100", "mapping.iters=2", "mapping.iters_first=3",
        "mapping.pixels=200", "rendering.n_stratified=6", "rendering.n_importance=2", "mapping.every_frame=2"]


def _copy_with_truncated(src: Path, dst: Path, truncate: list[int]) -> list[str]:
    """``src`` linked file by file into ``dst``, with the depth PNGs of the given associated pairs cut in half."""
    dst.mkdir()
    for name in os.listdir(src):
        if name not in ("rgb", "depth"):
            os.symlink(src / name, dst / name)
    (dst / "rgb").mkdir()
    (dst / "depth").mkdir()
    for name in os.listdir(src / "rgb"):
        os.symlink(src / "rgb" / name, dst / "rgb" / name)
    pairs = [line.split() for line in (src / "associations.txt").read_text().splitlines()
             if line.strip() and not line.startswith("#")]
    cut = {pairs[i][3] for i in truncate}
    for name in os.listdir(src / "depth"):
        if f"depth/{name}" in cut:
            data = (src / "depth" / name).read_bytes()
            (dst / "depth" / name).write_bytes(data[: len(data) // 2])
        else:
            os.symlink(src / "depth" / name, dst / "depth" / name)
    return sorted(Path(c).name for c in cut)


@pytest.fixture()
def excerpt(shared_data):
    p = shared_data / "tum_fr1_rpy"
    if not p.is_dir():
        pytest.skip("tum_fr1_rpy excerpt missing")
    return p


# read on the reader thread (sequential loop), and in the tracker's waits for a mapper thread
@pytest.mark.parametrize("reader", [[], ["parallel=true", "data.prefetch_in=waits"]], ids=["thread", "waits"])
def test_a_truncated_png_mid_run_is_skipped_and_listed(excerpt, tmp_path, reader):
    from slam.run.runner import run_to_folder

    data = tmp_path / "tum_fr1_rpy"  # the folder name tells the loader the camera (fr1)
    names = _copy_with_truncated(excerpt, data, [3])
    cfg = load_config("tum/fr1_rpy-cpu", [f"data.path={data}", *FAST, "data.max_bad_fraction=0.2", *reader])
    m = run_to_folder(cfg, tmp_path / "out", progress=False, mesh=False)
    bad = [e for e in m["events"] if e.get("bad_frame")]
    assert [e["frame"] for e in bad] == [3] and names[0] in bad[0]["event"]
    assert m["num_frames"] == 8 and not m.get("partial")
    lines = [ln for ln in (tmp_path / "out" / "trajectory.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(lines) == 8


def test_too_many_bad_frames_stop_the_run_after_writing_its_outputs(excerpt, tmp_path, capsys):
    from slam.cli import main

    data = tmp_path / "tum_fr1_rpy"  # the folder name tells the loader the camera (fr1)
    _copy_with_truncated(excerpt, data, [2, 3, 4])
    out = tmp_path / "out"
    code = main(["run", "--config", "tum/fr1_rpy-cpu", "--data", str(data), "--out", str(out), "--quiet",
                 "--no-mesh", *FAST, "data.max_bad_fraction=0.2", "checkpoint_every=1"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("lrslam run: error: 2 of the first") and "max_bad_fraction = 0.2" in err[-1]
    m = json.loads((out / "metrics.json").read_text())
    assert m["partial"] is True and "max_bad_fraction" in m["error"] and m["frames_done"] == 4
    assert (out / "trajectory.txt").is_file()
    from slam.run.checkpoint import load_run

    # the checkpoint is the last good one (after frame 2), not the state over the limit: resuming it with a
    # higher limit goes on; from the failing state it would fail again after one frame
    assert load_run(out / "checkpoint.pt")["extra"]["run"]["next"] == 3
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh", "data.max_bad_fraction=0.5"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert not m.get("partial") and m["num_frames"] == 8 and m["resumed_from"] == 3


def _system(tiny_seq, overrides=(), **edit):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *FAST, *overrides], profile="quality")
    return SLAM(cfg, EditedDataset(load_data(cfg), **edit))


def test_frame_0_without_depth_starts_the_map_at_the_first_frame_with_depth(tiny_seq):
    s = _system(tiny_seq, no_depth=[0, 1])
    s.run(progress=False)
    texts = [e["event"] for e in s.state.events]
    assert texts[0].startswith("no valid depth: the map starts at the first frame that has depth")
    assert texts[1].startswith("no valid depth: not tracked, previous pose used")
    assert texts[2].startswith("no map yet (no earlier frame had depth): not tracked")
    assert s.state.initialized and len(s.keyframes) >= 1 and s.keyframes.frames[0].index == 2
    assert s.state.trusted == [True, False, True] + [True] * 5  # frame 0 keeps its ground-truth pose
    s.close()


def test_event_text_names_the_prediction_used(tiny_seq):
    s = _system(tiny_seq, no_depth=[1, 4], overrides=["tracking.without_depth=predict"])
    s.run(progress=False)
    texts = {e["frame"]: e["event"] for e in s.state.events}
    assert texts[1] == "no valid depth: not tracked, previous pose used"
    assert texts[4] == "no valid depth: not tracked, constant-velocity pose used"
    s.close()
    s = _system(tiny_seq, no_depth=[1, 4])  # tracked on colour from the same predictions (or, if not taken, them)
    s.run(progress=False)
    texts = {e["frame"]: e["event"] for e in s.state.events}
    assert texts[1].startswith("no valid depth: ") and "from the previous pose" in texts[1] or (
        texts[1].startswith("no valid depth: colour tracking not taken") and "previous pose used" in texts[1]), texts
    assert "constant-velocity pose" in texts[4] and s.state.trusted[1] is s.state.trusted[4] is False, texts
    s.close()


def test_an_invalid_frame_0_ground_truth_starts_from_the_first_valid_one(tiny_seq):
    s = _system(tiny_seq, bad_gt=[0, 1])
    ref = s.ds.gt_poses[2]
    assert torch.equal(s.c2w0, ref)
    aabb = s.aabb
    c = ref[:3, 3]
    assert bool(((c >= aabb[:, 0]) & (c <= aabb[:, 1])).all())  # the start is inside the preset's box
    s.step(0)
    assert "ground truth of frame 2" in s.state.events[0]["event"]
    s.close()
