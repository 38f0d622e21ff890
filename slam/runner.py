"""A whole SLAM run into a folder: data, the loop, checkpoints, interrupts, then every output (:mod:`slam.outputs`).

A run never loses the work it has done:

* a checkpoint (:mod:`slam.checkpoint`) is written every ``checkpoint_every`` frames, or, with
  ``checkpoint_every: 0``, whenever ``checkpoint_interval_s`` seconds have passed since the last one, and at
  the end; ``run_to_folder(..., resume=True)`` (``lrslam run --resume OUT``) goes on from the latest;
* SIGINT / SIGTERM finish the frame in progress, then write the trajectory so far, a checkpoint and a
  ``metrics.json`` marked ``"partial": true``, and raise :class:`RunInterrupted` (the CLI exits 130 / 143);
* an error inside the loop writes the trajectory so far and a partial ``metrics.json`` (with the error) before it
  propagates; the last checkpoint stays as it was.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Sequence

import yaml

from slam.checkpoint import load_run, restore, save_checkpoint
from slam.config import Config, config_from_dict, save_config
from slam.errors import SlamInputError
from slam.observers import Observer
from slam.outputs import trajectory_metrics, write_frames, write_mesh, write_metrics, write_trajectories
from slam.setup import load_data, resolve_device
from slam.system import SLAM

log = logging.getLogger("slam")


class RunInterrupted(Exception):
    """A run stopped by a signal after writing its partial outputs; ``exit_code`` is 128 + the signal number."""

    def __init__(self, signum: int, out: Path, done: int, total: int):
        self.signum, self.out, self.done, self.total = signum, out, done, total
        self.exit_code = 128 + signum
        name = signal.Signals(signum).name
        super().__init__(f"{name}: stopped after frame {done} of {total}; outputs so far in {out}. "
                         f"Resume with: lrslam run --resume {out}")


@contextlib.contextmanager
def _signals_caught():
    """SIGINT and SIGTERM set a flag (read after each frame) instead of killing the process mid-frame."""
    caught: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return
    old = {}

    def handler(signum, _frame):
        if caught:  # a second signal: the user insists
            raise KeyboardInterrupt
        caught.append(signum)
        log.warning("%s received: finishing the current frame, then writing a checkpoint",
                    signal.Signals(signum).name)

    for sig in (signal.SIGINT, signal.SIGTERM):
        old[sig] = signal.signal(sig, handler)
    try:
        yield caught
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def resume_config(out: str | Path) -> Config:
    """The config a run folder was started with (``OUT/config.yaml``)."""
    path = Path(out) / "config.yaml"
    if not path.is_file():
        raise SlamInputError(f"{out}: not a run folder (no config.yaml); nothing to resume")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SlamInputError(f"{path}: invalid YAML: {exc}") from None
    return config_from_dict(data, upgrade=True)


def _partial_outputs(system: SLAM, out: Path, error: str | None = None, checkpoint: bool = True) -> dict:
    if checkpoint:
        save_checkpoint(system, out / "checkpoint.pt")
    if system.state.est:
        write_trajectories(system, out)
        write_frames(system, out)
    metrics = trajectory_metrics(system, out)
    metrics.update(partial=True, frames_done=len(system.state.est), frames_total=len(system.indices))
    if error:
        metrics["error"] = error
    write_metrics(metrics, out)
    return metrics


def run_to_folder(cfg: Config, out: str | Path, progress: bool = True, mesh: bool = True,
                  observers: Sequence[Observer] = (), resume: bool = False) -> dict:
    """Run SLAM (or, with ``resume``, go on from ``out/checkpoint.pt``) and write every output to ``out``;
    returns the metrics dict (also ``metrics.json``).

    Outputs: ``trajectory.txt`` / ``trajectory_gt.txt`` (TUM format), ``mesh.ply`` (coloured, culled),
    ``trajectory.png``, ``config.yaml``, ``checkpoint.pt`` (tdfields self-describing checkpoint: config, scene
    state_dict, poses, and the run state to resume from) and ``metrics.json``.

    Raises:
        RunInterrupted: SIGINT / SIGTERM (after the partial outputs are written).
        SlamInputError: bad data or config (one line; e.g. too many unreadable frames, after the outputs).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(cfg.device)
    ds = load_data(cfg)
    ckpt = load_run(out / "checkpoint.pt") if resume else None
    if not resume:
        save_config(cfg, out / "config.yaml")
    system = None
    try:
        t_start = time.perf_counter()
        system = SLAM(cfg, ds, device)
        start = restore(system, ckpt) if ckpt is not None else 0
        if ckpt is not None:
            log.warning("resuming %s from frame %d of %d", out, start, len(system.indices))
        for obs in observers:
            obs.on_start(system)
        last_ckpt = {"t": time.perf_counter(), "k": start}

        def periodic(k: int) -> None:
            every, now = cfg.checkpoint_every, time.perf_counter()
            due = (k + 1 - last_ckpt["k"] >= every) if every > 0 else (now - last_ckpt["t"] >= cfg.checkpoint_interval_s)
            if due and k + 1 < len(system.indices):
                save_checkpoint(system, out / "checkpoint.pt")
                last_ckpt.update(t=time.perf_counter(), k=k + 1)

        with _signals_caught() as caught:
            try:
                system.run(progress=progress, observers=observers, start=start, should_stop=lambda: bool(caught),
                           on_frame=periodic)
            except Exception as exc:
                _partial_outputs(system, out, error=f"{type(exc).__name__}: {exc}",
                                 checkpoint=isinstance(exc, SlamInputError))
                raise
            if caught:
                _partial_outputs(system, out)
                raise RunInterrupted(caught[0], out, len(system.state.est), len(system.indices))
        t_loop = time.perf_counter() - t_start
        write_trajectories(system, out)
        write_frames(system, out)
        save_checkpoint(system, out / "checkpoint.pt")
        metrics = trajectory_metrics(system, out)
        metrics.update(loop_s=t_loop, resumed_from=start if ckpt is not None else None,
                       mapping_wait_s=system.mapper.wait_s, snapshot_s=system.mapper.snapshot_s)
        m = write_mesh(system, out, metrics) if mesh else None
        write_metrics(metrics, out)
        for obs in observers:
            obs.on_finish(system, metrics, m)
    finally:
        for obs in observers:
            obs.close()
        if system is not None:
            system.close()
    return metrics
