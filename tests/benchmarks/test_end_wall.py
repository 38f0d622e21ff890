"""benchmarks/end_wall.py: its error measure on a known rotation, and a replay that resumes a real (tiny) run."""

import json
import math
import sys
from pathlib import Path

import pytest
import torch

from tests.benchmarks.conftest import load_script

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "end_wall.py"


@pytest.fixture(scope="module")
def end_wall():
    sys.path.insert(0, str(SCRIPT.parent))
    return load_script("end_wall")


@pytest.fixture(scope="module")
def tiny_seq(tmp_path_factory):
    from slam.data.synthetic import SynthConfig, generate

    out = tmp_path_factory.mktemp("tiny_room")
    generate(out, SynthConfig(frames=6, height=60, width=80, supersample=1))
    return out


def test_errors_give_the_rotation_about_its_world_axis(end_wall):
    a = math.radians(10.0)
    est = torch.eye(4)
    est[:3, :3] = torch.tensor([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    est[:3, 3] = torch.tensor([0.03, 0.0, 0.04])
    e = end_wall.errors(est, torch.eye(4))
    assert e["cm"] == pytest.approx(5.0, abs=1e-4) and e["deg"] == pytest.approx(10.0, abs=1e-3)
    assert e["world_rotvec_deg"] == pytest.approx([10.0, 0.0, 0.0], abs=1e-3)


def test_replays_resume_the_checkpoint_and_repeat(end_wall, tiny_seq, tmp_path):
    sets = ["data.kind=auto", f"data.path={tiny_seq}", "data.max_frames=6", "parallel=false"]
    assert end_wall.main(["--config", "synthetic", "--set", *sets, "--resume-at", "4", "--until", "6",
                          "--variants", "", "tracking.icp_hold=0", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "end_wall.json").read_text())
    own, off = res["variants"]["(the run's config)"], res["variants"]["tracking.icp_hold=0"]
    assert [r["k"] for r in own["frames"]] == [4, 5]  # from the checkpoint of frame 4 on
    assert all(r["trusted"] and r["cm"] < 2.0 for r in own["frames"])  # the room tracked (measured: 0.3-0.5 cm)
    assert own["frames"] == off["frames"]  # the room has no blind direction: the hold changes nothing there
    assert (tmp_path / "prefix" / "trajectory.txt").exists()
