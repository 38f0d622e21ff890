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
RUN = [*TINY[1:], "data.max_frames=24", "checkpoint_every=2", "parallel=true", "mapper_process=true",
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
    proc = _cli("--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), *RUN)
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


def _stopped(out: Path, args: list[str], how: str, at: int) -> dict:
    """Run (``args``: a fresh run's, or ``--resume``) and stop it by ``how`` at frame ``at``: ``term`` (SIGTERM to
    the process group) or ``kill`` (SIGKILL to the mapping process) once a checkpoint has passed ``at``, ``raise`` or
    ``cut`` in the mapping call of frame ``at`` (``faults/sitecustomize.py``). Checks the one line and the exit
    code; returns the metrics."""
    from slam.run.checkpoint import load_run

    before = load_run(out / "checkpoint.pt")["extra"]["run"]["next"] if (out / "checkpoint.pt").exists() else 0
    proc = _cli(*args, fault=f"{how}:{at}" if how in ("raise", "cut") else "")
    if how in ("term", "kill"):  # a checkpoint this run wrote: its loop (and mapping process) runs
        _wait_for_checkpoint(out, max(at, before + 2), proc)
        if how == "term":
            os.killpg(proc.pid, signal.SIGTERM)
        else:
            os.kill(_mapping_child(proc.pid), signal.SIGKILL)  # as the out-of-memory killer does
    _, err = proc.communicate(timeout=300)
    line = _one_line_error(err)
    assert f"lrslam run --resume {out}" in line, err[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["partial"]
    if how == "term":
        assert proc.returncode == 143 and "error" not in metrics, err[-2000:]
        return metrics
    assert proc.returncode == 1 and "mapping process" in line and "mapping process" in metrics["error"], err[-2000:]
    if how == "raise":  # the child's traceback is kept for a bug report, off the terminal
        assert f"injected fault in the mapping call of frame {at}" in line
        assert "Traceback" in metrics["error_detail"] and "map_frame" in metrics["error_detail"]
    else:
        assert "SIGKILL" in line
    kept = load_run(out / "checkpoint.pt")["extra"]["run"]["next"]
    assert kept <= metrics["frames_done"] < 24  # the last periodic checkpoint, not the failed state
    return metrics


@pytest.mark.slow
@pytest.mark.parametrize("first,second", [("term", "raise"), ("cut", "kill")])
def test_a_mapping_process_stopped_or_failing_twice_resumes_to_the_uninterrupted_run(tiny_seq, tmp_path,
                                                                                    uninterrupted, first, second):
    """Two stops of one run, the first in the fresh run and the second in its resume, four ways between the two
    cases: SIGTERM to the process group (Slurm's scancel, a systemd stop, ``kill -TERM -PGID``: 20b7b9c's child died
    of it, and the run ended in a traceback, exit 1, with no checkpoint), SIGKILL to the mapping process, an
    exception inside it, and its death in the middle of sending its map. Each stop says so in one line and keeps a
    checkpoint; the last resume gives the uninterrupted run's trajectory byte for byte."""
    out = tmp_path / "run"
    frame = {"term": (4, 10), "kill": (4, 10), "raise": (6, 12), "cut": (6, 12)}
    _stopped(out, ["--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), *RUN],
             first, frame[first][0])
    _stopped(out, ["--resume", str(out)], second, frame[second][1])
    _resume_matches(out, uninterrupted)
