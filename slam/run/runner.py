"""A whole SLAM run into a folder: data, the loop, checkpoints, interrupts, then every output (:mod:`slam.run.outputs`).

A run never loses the work it has done:

* a checkpoint (:mod:`slam.run.checkpoint`) is written every ``checkpoint_every`` frames, or, with
  ``checkpoint_every: 0``, whenever ``checkpoint_interval_s`` seconds have passed since the last one, and at
  the end; ``run_to_folder(..., resume=True)`` (``lrslam run --resume OUT``) goes on from the latest;
* SIGINT / SIGTERM (or ``stop_after`` frames, or a ``stop_file`` appearing) finish the frame in progress, then
  write the trajectory so far, a checkpoint and a ``metrics.json`` marked ``"partial": true``, and raise
  :class:`RunInterrupted` (the CLI exits 130 / 143). Mapping calls still pending are kept in the checkpoint, not
  applied early, so the resumed run is the uninterrupted one, byte for byte, in both loop modes;
* a second SIGINT / SIGTERM stops at once: a mapping call in progress ends at its next iteration, nothing more is
  written, and the last checkpoint on disk is the one to resume from;
* an error inside the loop writes the trajectory so far and a partial ``metrics.json`` (with the error) before it
  propagates; the last checkpoint stays as it was (a state already over ``data.max_bad_fraction`` would only fail
  again after one frame; a mapping process that died took the map's replica with it). A mapping process that died
  or failed is :class:`slam.errors.SlamRunError` (one line; its traceback in ``metrics.json``'s ``error_detail``);
* an output that cannot be written (a full disk) stops the run with :class:`slam.errors.SlamOutputError` naming
  the file; every file written before is intact (:mod:`slam.files`).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Sequence

from slam.run.checkpoint import RESUME_KEYS, load_run, restore, save_checkpoint
from slam.config import Config, config_from_dict, save_config
from slam.config.presets import read_yaml
from slam.errors import SlamInputError, SlamRunError
from slam.engine.observers import Observer
from slam.run.outputs import trajectory_metrics, write_frames, write_mesh, write_metrics, write_trajectories
from slam.engine.setup import load_data, resolve_device
from slam.engine.system import SLAM

log = logging.getLogger("slam")


class RunInterrupted(Exception):
    """A run stopped by a signal (or on request: ``signum`` 0) after writing its partial outputs; ``exit_code`` is
    128 + the signal number (0 for a requested stop)."""

    def __init__(self, signum: int, out: Path, done: int, total: int):
        self.signum, self.out, self.done, self.total = signum, out, done, total
        self.exit_code = 128 + signum if signum else 0
        name = signal.Signals(signum).name if signum else "stop requested"
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


def resume_config(out: str | Path, overrides: dict | None = None) -> Config:
    """The config a run folder was started with (``OUT/config.yaml``), with ``overrides`` (dotted key -> value)
    of :data:`slam.run.checkpoint.RESUME_KEYS` only: keys that decide when a run stops or writes, not what it computes.
    """
    path = Path(out) / "config.yaml"
    if not path.is_file():
        raise SlamInputError(f"{out}: not a run folder (no config.yaml); nothing to resume")
    data = read_yaml(path, "run config")
    if not data:
        raise SlamInputError(f"{path}: an empty config; nothing to resume")
    for key, value in (overrides or {}).items():
        if key not in RESUME_KEYS:
            raise SlamInputError(f"--resume continues a run with its own config: '{key}' would change what it "
                                 f"computes (a resumed run may change only {', '.join(RESUME_KEYS)})")
        *parents, leaf = key.split(".")
        node = data
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return config_from_dict(data, upgrade=True)


def _partial_outputs(system: SLAM, out: Path, error: str | None = None, checkpoint: bool = True,
                     detail: str = "") -> dict:
    if checkpoint:
        save_checkpoint(system, out / "checkpoint.pt")
    run = system.view()
    if system.state.est:
        write_trajectories(run, out)
        write_frames(run, out)
    metrics = trajectory_metrics(run, out)
    metrics.update(partial=True, frames_done=len(system.state.est), frames_total=len(system.indices))
    if error:
        metrics["error"] = error
    if detail:
        metrics["error_detail"] = detail
    write_metrics(metrics, out)
    return metrics


def run_to_folder(cfg: Config, out: str | Path, progress: bool = True, mesh: bool = True,
                  observers: Sequence[Observer] = (), resume: bool = False, stop_after: int | None = None,
                  stop_file: str | Path | None = None) -> dict:
    """Run SLAM (or, with ``resume``, go on from ``out/checkpoint.pt``) and write every output to ``out``;
    returns the metrics dict (also ``metrics.json``).

    Outputs: ``trajectory.txt`` / ``trajectory_gt.txt`` (TUM format), ``mesh.ply`` (coloured, culled),
    ``trajectory.png``, ``config.yaml``, ``checkpoint.pt`` (tdfields self-describing checkpoint: config, scene
    state_dict, poses, and the run state to resume from) and ``metrics.json``.

    Args:
        stop_after: stop as an interrupt would once this many frames are done (a resumable partial run).
        stop_file: stop as an interrupt would once this file exists (how ``lrslam sweep`` stops its runs).

    Raises:
        RunInterrupted: SIGINT / SIGTERM, ``stop_after`` or ``stop_file`` (after the partial outputs are written).
        SlamInputError: bad data or config (one line; e.g. too many unreadable frames, after the outputs).
        SlamOutputError: an output could not be written (what was written before is intact).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(cfg.device)
    ds = load_data(cfg)
    ckpt = load_run(out / "checkpoint.pt", cfg) if resume else None
    if not resume:
        save_config(cfg, out / "config.yaml")
    system = None
    abort = False
    try:
        t_start = time.perf_counter()
        system = SLAM(cfg, ds, device)
        start = restore(system, ckpt) if ckpt is not None else 0
        if ckpt is not None:
            log.warning("resuming %s from frame %d of %d", out, start, len(system.indices))
        for obs in observers:
            obs.on_start(system.view())
        _loop(system, out, cfg, start, progress, observers, stop_after, stop_file)
        t_loop = time.perf_counter() - t_start
        run = system.view()
        write_trajectories(run, out)
        write_frames(run, out)
        save_checkpoint(system, out / "checkpoint.pt")
        metrics = trajectory_metrics(run, out)
        metrics.update(loop_s=t_loop, resumed_from=start if ckpt is not None else None,
                       mapping_wait_s=system.mapper.wait_s, snapshot_s=system.mapper.snapshot_s,
                       mapping_s=system.mapper.map_s, mapping_calls=system.mapper.calls,
                       mapping_declined=system.mapper.declined, preload_s=system.preload_s)
        m = write_mesh(run, out, metrics) if mesh else None
        write_metrics(metrics, out)
        for obs in observers:
            obs.on_finish(run, metrics, m)
    except BaseException as exc:
        abort = not isinstance(exc, Exception)  # a second Ctrl-C (KeyboardInterrupt): do not wait for anything
        raise
    finally:
        for obs in observers:
            obs.close()
        if system is not None:
            system.close(abort=abort)
    return metrics


class Checkpoints(Observer):
    """Writes ``path`` every ``checkpoint_every`` frames (or, with 0, once ``checkpoint_interval_s`` seconds have
    passed since the last one), never after the last frame (the run's end writes it)."""

    def __init__(self, system: SLAM, path: Path, cfg: Config, start: int):
        self.system, self.path, self.cfg = system, path, cfg
        self.t, self.k = time.perf_counter(), start

    def on_frame(self, run, record) -> None:
        k, every = record.k, self.cfg.checkpoint_every
        due = (k + 1 - self.k >= every) if every > 0 else (time.perf_counter() - self.t >= self.cfg.checkpoint_interval_s)
        if due and k + 1 < len(run.indices):
            save_checkpoint(self.system, self.path)
            self.t, self.k = time.perf_counter(), k + 1


class StopWhen(Observer):
    """Asks the loop to stop after a frame once ``stop_after`` frames are done, ``stop_file`` exists, or a signal
    was caught (``caught`` non-empty)."""

    def __init__(self, stop_after: int | None, stop_file: str | Path | None, caught: list[int]):
        self.stop_after, self.stop_file, self.caught = stop_after, stop_file, caught
        self.done = 0

    def on_frame(self, run, record) -> None:
        self.done = run.done

    def stop_requested(self) -> bool:
        if self.stop_after is not None and self.done >= self.stop_after:
            return True
        if self.stop_file is not None and Path(self.stop_file).exists():
            return True
        return bool(self.caught)


def _loop(system: SLAM, out: Path, cfg: Config, start: int, progress: bool, observers, stop_after, stop_file):
    """The frames from ``start``, with periodic checkpoints; on a stop, the partial outputs and RunInterrupted."""
    with _signals_caught() as caught:
        own = [Checkpoints(system, out / "checkpoint.pt", cfg, start), StopWhen(stop_after, stop_file, caught)]
        try:
            system.run(progress=progress, observers=[*observers, *own], start=start)
        except Exception as exc:
            # the last checkpoint stays: this state may be the one that failed (too many bad frames)
            _partial_outputs(system, out, error=f"{type(exc).__name__}: {exc}", checkpoint=False,
                             detail=getattr(exc, "detail", ""))
            if isinstance(exc, SlamRunError):
                raise SlamRunError(f"{exc}: stopped after frame {len(system.state.est)} of {len(system.indices)}; "
                                   f"outputs so far in {out}. Resume from its last checkpoint with: "
                                   f"lrslam run --resume {out}", exc.detail) from exc
            raise
        if len(system.state.est) < len(system.indices):
            _partial_outputs(system, out)
            raise RunInterrupted(caught[0] if caught else 0, out, len(system.state.est), len(system.indices))
