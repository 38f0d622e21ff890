"""Faults of the mapper process (``mapper_process: true``) through the command line: a stop of the whole process
group, the child killed, an exception inside it and a death in the middle of a map's handover. Each ends with one
line (no traceback), the work done kept (a checkpoint written at the stop, or the last periodic one), and a
``--resume`` that gives the uninterrupted run's trajectory byte for byte."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.slam.conftest import TINY
from tests.slam.run.test_runner import _wait_for_checkpoint

ROOT = Path(__file__).resolve().parents[3]
FAULTS = Path(__file__).resolve().parent / "faults"
# the process mapper with the settings that meet it: carried Adam moments (the child holds them), a bounded keyframe
# store (the child drops, the loop mirrors); every second frame mapped, a checkpoint every second frame
RUN = [*TINY[1:], "data.max_frames=16", "checkpoint_every=2", "parallel=true", "mapper_process=true",
       "mapping.every_frame=2", "mapping.keyframe_every=2", "mapping.optimizer_state=persistent",
       "mapping.max_keyframes=3"]


def _cli(*args, fault: str = "", **kw):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(FAULTS), str(ROOT)]), OMP_NUM_THREADS="1")
    if fault:
        env["LRSLAM_TEST_FAULT"] = fault
    cmd = [sys.executable, "-m", "slam.cli", "run", "--quiet", "--no-mesh", *args]
    return subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kw)


@pytest.fixture(scope="module")
def uninterrupted(tiny_seq, tmp_path_factory):
    out = tmp_path_factory.mktemp("straight")
    proc = _cli("--data", str(tiny_seq), "--out", str(out), *RUN)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    return (out / "trajectory.txt").read_text()


def _mapping_child(pid: int) -> int:
    """The pid of the run's mapping process (not multiprocessing's resource tracker)."""
    for kid in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        if "spawn_main" in Path(f"/proc/{kid}/cmdline").read_text():
            return int(kid)
    raise AssertionError("no mapping process found")


def _one_line_error(err: str) -> str:
    assert "Traceback" not in err, err[-2000:]
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("lrslam run:")]
    assert len(lines) == 1, err[-2000:]
    return lines[0]


def _resume_matches(out: Path, uninterrupted: str) -> None:
    done = _cli("--resume", str(out))
    _, err = done.communicate(timeout=300)
    assert done.returncode == 0, err[-2000:]
    assert (out / "trajectory.txt").read_text() == uninterrupted  # byte for byte


@pytest.mark.slow
def test_sigterm_to_the_process_group_writes_a_checkpoint_and_resumes_exactly(tiny_seq, tmp_path, uninterrupted):
    """Slurm's scancel, a systemd stop and ``kill -TERM -PGID`` reach the mapping process too: it must leave the stop
    to the loop (20b7b9c's child died of it, and the run ended in a traceback, exit 1, with no checkpoint)."""
    out = tmp_path / "run"
    proc = _cli("--data", str(tiny_seq), "--out", str(out), *RUN)
    _wait_for_checkpoint(out, 4, proc)
    os.killpg(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err[-2000:]
    assert f"lrslam run --resume {out}" in _one_line_error(err)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["partial"] and "error" not in metrics
    _resume_matches(out, uninterrupted)


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["kill", "raise:10", "cut:10"])
def test_a_mapping_process_that_dies_or_raises_stops_in_one_line_and_resumes_exactly(tiny_seq, tmp_path,
                                                                                     uninterrupted, fault):
    out = tmp_path / "run"
    proc = _cli("--data", str(tiny_seq), "--out", str(out), *RUN, fault="" if fault == "kill" else fault)
    if fault == "kill":
        _wait_for_checkpoint(out, 4, proc)
        os.kill(_mapping_child(proc.pid), signal.SIGKILL)  # as the out-of-memory killer does
    _, err = proc.communicate(timeout=300)
    line = _one_line_error(err)
    assert proc.returncode == 1 and "mapping process" in line and f"lrslam run --resume {out}" in line, err[-2000:]
    if fault != "raise:10":
        assert "SIGKILL" in line
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["partial"] and "mapping process" in metrics["error"]
    if fault == "raise:10":  # the child's traceback is kept for a bug report, off the terminal
        assert "injected fault in the mapping call of frame 10" in line
        assert "Traceback" in metrics["error_detail"] and "map_frame" in metrics["error_detail"]
    from slam.run.checkpoint import load_run

    kept = load_run(out / "checkpoint.pt")["extra"]["run"]["next"]
    assert 4 <= kept <= metrics["frames_done"] < 16  # the last periodic checkpoint, not the failed state
    _resume_matches(out, uninterrupted)
