"""A run never loses its work: kill -9 then --resume gives the uninterrupted trajectory; SIGINT / SIGTERM write
partial outputs and exit 130 / 143 with one line saying how to resume."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from slam.engine.observers import Observer
from tests.slam.conftest import GROWING, TINY

ROOT = Path(__file__).resolve().parents[3]
RUN = TINY[1:] + ["data.max_frames=10", "checkpoint_every=2"]  # TINY[0] is data.max_frames=6


def _cmd(*args):
    return [sys.executable, "-m", "slam.cli", "run", "--quiet", "--no-mesh", *args]


def _env():
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    return env


def _wait_for_checkpoint(out: Path, at_least: int, proc, timeout=240.0) -> int:
    """Poll OUT/checkpoint.pt until it holds a run state with ``next >= at_least``."""
    from slam.run.checkpoint import load_run

    t0 = time.time()
    while time.time() - t0 < timeout:
        if proc.poll() is not None:
            raise AssertionError(f"run ended early ({proc.returncode}): {proc.stderr.read().decode()[-2000:]}")
        p = out / "checkpoint.pt"
        if p.is_file():
            try:
                nxt = load_run(p)["extra"]["run"]["next"]
            except Exception:  # being replaced right now
                nxt = -1
            if nxt >= at_least:
                return nxt
        time.sleep(0.2)
    raise AssertionError("no checkpoint appeared in time")


@pytest.fixture(scope="module")
def uninterrupted(tiny_seq, tmp_path_factory):
    """The runs straight through, in this process (a run is the same in or out of it: one torch thread either way)."""
    from slam.config import load_config
    from slam.run.runner import run_to_folder

    out = {}
    for mode in ("true",):
        d = tmp_path_factory.mktemp(f"full-{mode}")
        run_to_folder(load_config("synthetic", [f"data.path={tiny_seq}", *RUN, f"parallel={mode}"], profile="quality"), d,
                      progress=False, mesh=False)
        out[mode] = d
    return out


@pytest.mark.slow
@pytest.mark.parametrize("parallel", ["true"])  # the default mode; both modes are stopped and resumed below
def test_kill_9_then_resume_gives_the_uninterrupted_trajectory(tiny_seq, tmp_path, uninterrupted, parallel):
    out = tmp_path / "run"
    proc = subprocess.Popen(_cmd("--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), *RUN, f"parallel={parallel}"),
                            env=_env(), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    nxt = _wait_for_checkpoint(out, 4, proc)
    proc.kill()  # SIGKILL: no handler runs, only the checkpoint on disk survives
    proc.wait()
    assert not (out / "metrics.json").exists()
    # as a kill in the middle of writing the next checkpoint leaves it: half a file under the temporary name
    (out / ".checkpoint.tmp.pt").write_bytes((out / "checkpoint.pt").read_bytes()[:1000])
    done = subprocess.run(_cmd("--resume", str(out)), env=_env(), cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["resumed_from"] >= nxt and metrics["num_frames"] == 10 and not metrics.get("partial")
    ours = (out / "trajectory.txt").read_text()
    ref = (uninterrupted[parallel] / "trajectory.txt").read_text()
    assert ours == ref  # bit for bit: scene, keyframes, random states and schedule all came back
    again = subprocess.run(_cmd("--resume", str(out)), env=_env(), cwd=ROOT, capture_output=True, text=True)
    assert again.returncode == 0 and "complete" in again.stdout


@pytest.mark.slow
@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143)])  # SIGINT: in this process, below
def test_signal_finishes_the_frame_writes_partial_outputs_and_says_how_to_resume(tiny_seq, tmp_path, sig, code):
    out = tmp_path / "run"
    # all 24 frames: with 10, a fast machine finished the last 8 between the checkpoint's poll and the signal
    # (the run then ends complete, exit 0)
    run = TINY[1:] + ["data.max_frames=24", "checkpoint_every=2"]
    proc = subprocess.Popen(_cmd("--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), *run), env=_env(), cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _wait_for_checkpoint(out, 2, proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=240)
    err = err.decode()
    assert proc.returncode == code, err[-2000:]
    assert "Traceback" not in err
    last = [line for line in err.strip().splitlines() if line.startswith("lrslam run:")]
    assert len(last) == 1 and f"lrslam run --resume {out}" in last[0]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["partial"] is True and 2 <= metrics["frames_done"] < 24
    lines = [ln for ln in (out / "trajectory.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(lines) == metrics["frames_done"]
    from slam.run.checkpoint import load_run

    assert load_run(out / "checkpoint.pt")["extra"]["run"]["next"] == metrics["frames_done"]


def test_resume_refuses_other_settings_and_non_run_folders(tmp_path, capsys):
    from slam.cli import main

    assert main(["run", "--resume", str(tmp_path), "tracking.iters=3"]) == 2
    assert "not a run folder" in capsys.readouterr().err
    (tmp_path / "config.yaml").write_text("seed: 0\n")
    assert main(["run", "--resume", str(tmp_path), "tracking.iters=3"]) == 2
    assert "'tracking.iters' would change what it computes" in capsys.readouterr().err
    assert main(["run", "--resume", str(tmp_path), "--config", "synthetic"]) == 2
    assert "drop --config" in capsys.readouterr().err


# ------------------------------------------------------------------------------ stops, resumes and damaged files
INPROC = TINY[1:] + ["data.max_frames=10"]  # synthetic maps frames 0, 4, 8 and the last: in parallel mode the
# call of frame 4 is still pending (lag 4) while frames 5-7 are tracked


class _SignalAt(Observer):
    """An observer that sends this process SIGINT after frame ``k``, as a user's Ctrl-C would."""

    def __init__(self, k: int):
        self.k = k

    def on_frame(self, run, rec):
        if rec.k == self.k:
            os.kill(os.getpid(), signal.SIGINT)


def _traj(out: Path) -> str:
    return (out / "trajectory.txt").read_text()


# the map's Adam moments carried between calls (mapping.optimizer_state: persistent) are in the checkpoint too: the
# resumed run's next call starts from them (in parallel mode, from those of the call still pending)
@pytest.mark.parametrize("parallel,state", [("true", "persistent"), ("false", "per_call")])
def test_an_interrupt_with_a_mapping_call_pending_resumes_to_the_uninterrupted_run(tiny_seq, tmp_path, parallel,
                                                                                   state):
    from slam.run.checkpoint import load_run
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, run_to_folder

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *INPROC, f"parallel={parallel}",
                                    f"mapping.optimizer_state={state}"], profile="quality")
    run_to_folder(cfg, tmp_path / "full", progress=False, mesh=False)
    for at in (2, 5):
        out = tmp_path / f"stopped-at-{at}"
        with pytest.raises(RunInterrupted) as info:
            run_to_folder(cfg, out, progress=False, mesh=False, observers=[_SignalAt(at)])
        assert info.value.exit_code == 130 and info.value.done == at + 1
        pending = load_run(out / "checkpoint.pt")["extra"]["run"]["pending"]
        # the point of the test: a call submitted at frame 4 is still owed to the schedule when frame 5 stops
        assert [p["k"] for p in pending] == ([4] if parallel == "true" and at == 5 else [])
        run_to_folder(cfg, out, progress=False, mesh=False, resume=True)
        assert _traj(out) == _traj(tmp_path / "full"), f"stopped after frame {at}"


def test_carried_map_moments_come_back_with_a_resume(tiny_seq, tmp_path, monkeypatch):
    """``mapping.optimizer_state: persistent`` with every frame mapped: the checkpoint holds the moments and the
    resumed run is the uninterrupted one; a resume that starts them afresh (the checkpoint's moments dropped) ends
    elsewhere, so they are what carries it. (A mapper process's new child starting from them: test_map_process.)"""
    import shutil

    import slam.engine.map_worker as map_worker
    from slam.config import load_config
    from slam.engine.mapper import MapMoments
    from slam.errors import SlamInputError
    from slam.run.checkpoint import load_run
    from slam.run.runner import RunInterrupted, run_to_folder

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=false", "mapping.every_frame=1",
                                    "mapping.keyframe_every=1", "mapping.optimizer_state=persistent"], profile="quality")
    run_to_folder(cfg, tmp_path / "full", progress=False, mesh=False)
    out = tmp_path / "stopped"
    with pytest.raises(RunInterrupted):
        run_to_folder(cfg, out, progress=False, mesh=False, stop_after=3)
    moments = load_run(out / "checkpoint.pt")["extra"]["run"]["moments"]
    # frames 1 and 2, 3 iterations each
    assert {float(v["step"]) for v in moments.values()} == {6.0}
    shutil.copytree(out, tmp_path / "dropped")
    payload = torch.load(out / "checkpoint.pt", weights_only=True)
    name = next(iter(payload["extra"]["run"]["moments"]))
    payload["extra"]["run"]["moments"][name]["exp_avg_sq"].view(-1)[0] = float("inf")
    (tmp_path / "poisoned").mkdir()
    shutil.copy(out / "config.yaml", tmp_path / "poisoned" / "config.yaml")
    torch.save(payload, tmp_path / "poisoned" / "checkpoint.pt")
    with pytest.raises(SlamInputError, match=f"carried Adam moments holds 1 non-finite value\\(s\\) in {name}"):
        run_to_folder(cfg, tmp_path / "poisoned", progress=False, mesh=False, resume=True)
    run_to_folder(cfg, out, progress=False, mesh=False, resume=True)
    assert _traj(out) == _traj(tmp_path / "full")
    monkeypatch.setattr(map_worker, "MapMoments", lambda state=None: MapMoments(None))
    run_to_folder(cfg, tmp_path / "dropped", progress=False, mesh=False, resume=True)
    assert _traj(tmp_path / "dropped") != _traj(tmp_path / "full")


@pytest.mark.parametrize("parallel,state", [("true", "per_call"), ("false", "persistent")])
def test_a_run_stopped_after_its_box_grew_resumes_to_the_uninterrupted_run(tiny_seq, tmp_path, parallel, state):
    """The checkpoint holds the grown map (and, in parallel mode, the grown maps of the calls still pending) and
    the grown boxes; the resumed run rebuilds its scene at that size. frames.csv shows the size frame by frame, and
    ``lrslam mesh`` rebuilds the grown map."""
    import csv

    from slam.commands.mesh import load_run_checkpoint
    from slam.config import load_config
    from slam.run.checkpoint import load_run
    from slam.run.runner import RunInterrupted, run_to_folder

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *INPROC, *GROWING, f"parallel={parallel}",
                                    f"mapping.optimizer_state={state}"], profile="quality")
    full = run_to_folder(cfg, tmp_path / "full", progress=False, mesh=False)
    at = next(e["frame"] for e in full["events"] if "growth" in e)  # stride 1: frame index = position
    out = tmp_path / "stopped"
    with pytest.raises(RunInterrupted):
        run_to_folder(cfg, out, progress=False, mesh=False, stop_after=at + 1)
    extra = load_run(out / "checkpoint.pt")["extra"]
    assert extra["aabb"][0][0] < -1.6 and extra["run"]["growth"]["aabb"].tolist() == extra["aabb"]
    assert extra["marching_cubes_bound"][0][0] < -1.6 and extra["bound"][0][0] < -1.6
    _, scene, _ = load_run_checkpoint(out / "checkpoint.pt")  # lrslam mesh: the grown map, at its size
    assert scene.aabb.tolist() == extra["aabb"]
    run_to_folder(cfg, out, progress=False, mesh=False, resume=True)
    assert _traj(out) == _traj(tmp_path / "full")
    sizes = [(int(r["parameters"]), int(r["field_bytes"])) for r in csv.DictReader((out / "frames.csv").open())]
    full_rows = list(csv.DictReader((tmp_path / "full" / "frames.csv").open()))
    assert sizes == [(int(r["parameters"]), int(r["field_bytes"])) for r in full_rows]
    assert len(set(sizes[:at])) == 1 and sizes[at][0] > sizes[at - 1][0] and sizes[at][1] > sizes[at - 1][1]


def test_stop_after_and_a_damaged_or_foreign_checkpoint(tiny_seq, tmp_path, capsys):
    """--stop-after is a resumable stop; a truncated checkpoint is refused in one line and the one before it is
    kept, and so is one whose map holds NaN (naming the tensor); a checkpoint written under another config than
    config.yaml is refused, naming the key."""
    from slam.run.checkpoint import previous_path
    from slam.cli import main

    out = tmp_path / "run"
    base = ["run", "--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), "--quiet", "--no-mesh", *INPROC, "checkpoint_every=2"]
    assert main([*base, "--stop-after", "5"]) == 0
    assert "Resume with: lrslam run --resume" in capsys.readouterr().err
    ckpt, prev = out / "checkpoint.pt", previous_path(out / "checkpoint.pt")
    assert prev.is_file() and prev.read_bytes() != ckpt.read_bytes()  # periodic at 4, the stop's at 5
    for damaged in (ckpt.read_bytes()[: ckpt.stat().st_size // 2], b""):  # a truncated copy, an empty file
        ckpt.write_bytes(damaged)
        assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not a readable checkpoint" in err[0] and f"mv {prev} {ckpt}" in err[0]
        assert prev.is_file()  # refusing leaves the one before as it was
    payload = torch.load(prev, weights_only=True)
    del payload["extra"]["run"]["guard"]  # readable, but a part of the run state is gone
    torch.save(payload, ckpt)
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "run state is incomplete or damaged (KeyError: 'guard')" in err[0]
    payload = torch.load(prev, weights_only=True)
    name = next(k for k, t in payload["state_dict"].items() if t.numel() > 2)
    payload["state_dict"][name].view(-1)[:2] = float("nan")  # readable, but the map is poisoned
    torch.save(payload, ckpt)
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"the map holds 2 non-finite value(s) in {name}" in err[0] and f"mv {prev}" in err[0]
    prev.replace(ckpt)
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 0
    # a new run with another config started into the folder (it writes config.yaml first) and killed before its
    # first checkpoint: the checkpoint on disk is the old run's
    from slam.config import load_config, save_config

    save_config(load_config("synthetic", [f"data.path={tiny_seq}", *INPROC, "tracking.iters=4"], profile="quality"), out / "config.yaml")
    (out / "metrics.json").write_text('{"partial": true}')
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "written under another config" in err[0] and "tracking.iters" in err[0]


def test_a_checkpoint_of_an_earlier_version_resumes(tiny_seq, tmp_path, caplog):
    """A run folder written before the relocalisation keys existed (29d2223's format: its config and checkpoint
    lack them, the guard's history is a bare list, the run state has no reloc_tried_at) resumes; the keys it did
    not have take their defaults, and the log says so."""
    import yaml

    from slam.cli import main

    out = tmp_path / "old"
    assert main(["run", "--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), "--quiet", "--no-mesh", *INPROC,
                 "--stop-after", "5"]) == 0
    ckpt = out / "checkpoint.pt"
    payload = torch.load(ckpt, weights_only=True)
    new_keys = ("relocalize_after", "relocalize_keyframes")
    for key in new_keys:
        del payload["config"]["tracking"][key]
    run = payload["extra"]["run"]
    run["guard"] = run["guard"]["losses"]
    del run["state"]["reloc_tried_at"]
    torch.save(payload, ckpt)
    config = yaml.safe_load((out / "config.yaml").read_text())
    for key in new_keys:
        del config["tracking"][key]
    (out / "config.yaml").write_text(yaml.safe_dump(config))
    with caplog.at_level("WARNING", logger="slam"):
        assert main(["run", "--resume", str(out), "--no-mesh"]) == 0
    assert "written by an earlier version" in caplog.text and "tracking.relocalize_after=5" in caplog.text
    assert json.loads((out / "metrics.json").read_text())["num_frames"] == 10


def test_checkpoint_roundtrip_restores_every_piece_of_state(tiny_seq):
    from slam.run.checkpoint import RUN_FORMAT, checkpoint_extra, restore
    from slam.config import load_config
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *RUN], profile="quality")
    a = SLAM(cfg, load_data(cfg))
    for k in range(5):
        a.step(k)
    extra = checkpoint_extra(a.view())
    extra["run"] = {"format": RUN_FORMAT, "next": 5, **a.state_dict()}
    ckpt = {"state_dict": {k: v.clone() for k, v in a.scene.state_dict().items()}, "extra": extra}
    b = SLAM(cfg, load_data(cfg))
    assert restore(b, ckpt) == 5
    for k in range(5, 8):
        a.step(k)
        b.step(k)
    assert torch.equal(torch.stack(a.state.est), torch.stack(b.state.est))
    for (na, pa), (nb, pb) in zip(a.scene.state_dict().items(), b.scene.state_dict().items()):
        assert na == nb and torch.equal(pa, pb)
    a.close()
    b.close()


def test_a_full_disk_mid_run_stops_with_one_line_and_loses_nothing(tiny_seq, tmp_path, monkeypatch, capsys):
    """The disk fills after the checkpoint of frame 2: the next checkpoint fails, the run stops with one line
    naming the file, the checkpoint of frame 2 is intact (no temporary file left), and once there is room again
    --resume finishes it to the uninterrupted trajectory."""
    import errno

    import slam.files
    from slam.run.checkpoint import load_run
    from slam.cli import main

    args = ["--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--quiet", "--no-mesh", *INPROC, "checkpoint_every=2"]
    assert main(["run", "--out", str(tmp_path / "full"), *args]) == 0
    real, written = slam.files.fsync_file, []

    def full_after_one_checkpoint(path):
        if path.name.startswith(".checkpoint"):
            if written:
                raise OSError(errno.ENOSPC, "No space left on device")
            written.append(path)
        return real(path)

    monkeypatch.setattr(slam.files, "fsync_file", full_after_one_checkpoint)
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"lrslam run: error: {out / 'checkpoint.pt'}: checkpoint not written (No space left on "
                       "device); the previous file, if any, is intact")
    assert load_run(out / "checkpoint.pt")["extra"]["run"]["next"] == 2
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp.pt")]
    monkeypatch.setattr(slam.files, "fsync_file", real)
    assert main(["run", "--resume", str(out), "--quiet", "--no-mesh"]) == 0
    assert _traj(out) == _traj(tmp_path / "full")


@pytest.mark.slow
def test_a_second_ctrl_c_stops_at_once_during_a_long_mapping_call(tiny_seq, tmp_path):
    """The first Ctrl-C waits for the mapping call in progress (its checkpoint needs it); the second one ends that
    call at its next iteration and exits 130 without waiting for it (a warm-up of 100000 iterations here)."""
    out = tmp_path / "run"
    proc = subprocess.Popen(_cmd("--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), *RUN, "parallel=true",
                                 "mapping.iters_first=100000"), env=_env(), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    t0 = time.time()
    while not (out / "config.yaml").exists() and time.time() - t0 < 60:
        time.sleep(0.1)
    time.sleep(3.0)  # set up, the warm-up call running
    proc.send_signal(signal.SIGINT)
    time.sleep(1.0)
    assert proc.poll() is None  # still waiting for the warm-up
    t1 = time.time()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert time.time() - t1 < 10, "the second Ctrl-C waited for the mapping call"
    assert proc.returncode == 130 and "Traceback" not in err.decode()
