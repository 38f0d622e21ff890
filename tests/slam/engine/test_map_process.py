"""The mapper in its own process (``mapper_process: true``): the thread mode's run bit for bit, through a growth of
the box, a stop with a call pending and a resume; a child that dies is an error naming it, not a hang."""

import pytest
import torch

from slam.config import load_config
from slam.errors import SlamInputError
from tests.slam.conftest import GROWING, TINY

RUN = TINY[1:] + ["data.max_frames=10", *GROWING]  # synthetic maps frames 0, 4, 8, 9; the box grows once


def _traj(out) -> str:
    return (out / "trajectory.txt").read_text()


def test_a_mapper_process_gives_the_thread_modes_run_through_a_growth_a_stop_and_a_resume(tiny_seq, tmp_path):
    from slam.run.checkpoint import load_run
    from slam.run.runner import RunInterrupted, run_to_folder

    thread = load_config("synthetic", [f"data.path={tiny_seq}", *RUN, "parallel=true"])
    proc = load_config("synthetic", [f"data.path={tiny_seq}", *RUN, "parallel=true", "mapper_process=true"])
    full = run_to_folder(thread, tmp_path / "thread", progress=False, mesh=False)
    at = next(e["frame"] for e in full["events"] if "growth" in e)
    out = tmp_path / "process"
    with pytest.raises(RunInterrupted):
        run_to_folder(proc, out, progress=False, mesh=False, stop_after=at + 1)
    stopped = load_run(out / "checkpoint.pt")["extra"]
    assert stopped["aabb"][0][0] < -1.6, "stopped before the growth"
    assert [p["k"] for p in stopped["run"]["pending"]] == [4], "no call pending at the stop"
    done = run_to_folder(proc, out, progress=False, mesh=False, resume=True)  # a new child, from the checkpoint
    assert _traj(out) == _traj(tmp_path / "thread")  # bit for bit
    assert done["mapping_calls"] >= 1 and done["mapping_s"] > 0  # this session's calls, timed in the child
    a = load_run(tmp_path / "thread" / "checkpoint.pt")
    b = load_run(out / "checkpoint.pt")
    for name, t in a["state_dict"].items():
        assert torch.equal(t, b["state_dict"][name]), name
    ka, kb = a["extra"]["run"]["keyframes"], b["extra"]["run"]["keyframes"]
    assert [k["k"] for k in ka] == [k["k"] for k in kb]
    assert all(torch.equal(x["pose"], y["pose"]) for x, y in zip(ka, kb))  # BA's poses came back from the child
    assert torch.equal(a["extra"]["run"]["rng"]["map_gen"], b["extra"]["run"]["rng"]["map_gen"])


def test_a_dead_mapper_process_is_an_error_that_names_it(tiny_seq):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=true", "mapper_process=true"])
    s = SLAM(cfg, load_data(cfg))
    try:
        s.step(0)  # the warm-up: the child starts
        s.mapper.wait_idle()
        s.mapper.process._proc.kill()
        with pytest.raises(RuntimeError, match="mapping process ended unexpectedly"):
            for k in range(1, 6):
                s.step(k)
            s.finish()
    finally:
        s.close(abort=True)


def test_mapper_process_needs_parallel():
    with pytest.raises(SlamInputError, match="'mapper_process'"):
        load_config("synthetic", ["parallel=false", "mapper_process=true"])
