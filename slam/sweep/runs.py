"""Running a sweep: one run in its folder (reused when finished, resumed when interrupted), the engines that run
many (in this process, or as Ray tasks), and :func:`execute`."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Callable, Sequence

from slam.errors import SlamInputError

from slam.config.load import differing_keys, flatten
from slam.run.outputs import finished_metrics
from slam.sweep.plan import _TRACEBACK_LINES, RunSpec, _run_name
from slam.sweep.summary import summarize, write_summary


# --------------------------------------------------------------------------------------------------- one run
def interrupted(run_dir: str | Path) -> bool:
    """True for a run stopped by SIGINT / SIGTERM: partial metrics without an error, and its checkpoint."""
    try:
        m = json.loads((Path(run_dir) / "metrics.json").read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(m, dict) and bool(m.get("partial")) and not m.get("error")
            and (Path(run_dir) / "checkpoint.pt").is_file())


def failed_record(spec: RunSpec, exc: BaseException, tb: str | None = None) -> dict:
    """The record of a run that raised ``exc``: one-line error and the traceback's last lines."""
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    lines = (tb or "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))).rstrip().splitlines()
    return {**spec.identity(), "status": "failed", "error": f"{type(exc).__name__}: {msg}".rstrip(": "),
            "traceback": "\n".join(lines[-_TRACEBACK_LINES:])}


def run_one(spec: RunSpec) -> dict:
    """Run one sweep entry into its folder and return its record; never raises for a failing run.

    The full traceback of a failure also goes to ``run_dir/error.txt``.
    """
    from slam.config import load_config
    from slam.run.runner import RunInterrupted, resume_config, run_to_folder

    t0 = time.perf_counter()
    if spec.stop_file and Path(spec.stop_file).exists():
        return {**spec.identity(), "status": "interrupted", "error": "the sweep was stopped before this run started",
                "wall_s": 0.0}
    try:
        with contextlib.ExitStack() as stack:
            if spec.backend is not None:
                from tdfields import kernels

                stack.enter_context(kernels.use_backend(spec.backend))
            # a resumed run goes on under its own config.yaml (threads included), not the sweep's current one
            cfg = resume_config(spec.run_dir) if spec.resume else load_config(spec.preset, spec.config_overrides())
            metrics = run_to_folder(cfg, spec.run_dir, progress=spec.progress, mesh=spec.mesh, resume=spec.resume,
                                    stop_file=spec.stop_file)
    except RunInterrupted as exc:
        return {**spec.identity(), "status": "interrupted", "error": str(exc), "frames_done": exc.done,
                "wall_s": time.perf_counter() - t0}
    except Exception as exc:
        tb = traceback.format_exc()
        try:
            Path(spec.run_dir).mkdir(parents=True, exist_ok=True)
            (Path(spec.run_dir) / "error.txt").write_text(tb)
        except OSError:
            pass
        rec = failed_record(spec, exc, tb)
        rec["wall_s"] = time.perf_counter() - t0
        return rec
    return {**metrics, **spec.identity(), "status": "ok", "wall_s": time.perf_counter() - t0}


# --------------------------------------------------------------------------------------------------- engines
class SerialEngine:
    """Runs every spec in this process, one after another (debugging, tests, machines without Ray)."""

    name = "serial"

    def run(self, specs: Sequence[RunSpec], on_result: Callable[[dict], None]) -> None:
        for spec in specs:
            rec = run_one(spec)
            on_result(rec)
            if rec["status"] == "interrupted":  # Ctrl-C stopped the run (resumable): it stops the sweep too
                raise KeyboardInterrupt


def require_ray():
    """Import and return ``ray``; SlamInputError naming the install command if it is missing."""
    try:
        import ray
    except ImportError:
        from slam._deps import install_command

        raise SlamInputError(f"lrslam sweep runs on Ray, which is not installed; install the sweep extra: "
                             f"{install_command('sweep')} (or: python3 -m pip install \"ray>=2.9\")") from None
    return ray


def cpus_for(spec: RunSpec, cpus_per_run: int, available: float | None = None) -> float:
    """CPUs to reserve for one run: ``cpus_per_run`` per loop thread, i.e. twice that for a run in parallel mode
    (``parallel: true``: tracker and mapper each run one torch thread), capped at ``available``.

    Why: two parallel-mode runs at once on a 2-core machine (a third CPU-bound run beside them) ran 7.5x slower
    each (frame time 5.31 vs 0.71 s, the same trajectory): more busy threads than cores, and each process's GIL
    handed back and forth at every torch call. Reserving two CPUs runs them one after the other.
    """
    from slam.config import load_config

    loops = 2 if load_config(spec.preset, spec.config_overrides()).parallel else 1
    want = float(cpus_per_run * loops)
    return want if available is None else max(min(want, float(available)), 1e-3)


class RayEngine:
    """One Ray task per run (:func:`cpus_for`: ``cpus_per_run``, twice that in parallel mode), results handled as
    they finish.

    Args:
        address: a Ray cluster's address (``ray.init(address=...)``); None starts a local Ray for the sweep
            and stops it afterwards. A Ray already initialised in this process is used as it is.
        cpus_per_run: CPUs Ray reserves per loop thread of a run (also its torch thread count, see :func:`plan`).
        num_cpus: CPUs of the local Ray (None: all of this machine's); ignored with ``address``.
        init_kwargs: more ``ray.init`` arguments.

    Workers import ``slam`` and ``tdfields`` from where this process does: a local Ray gets this checkout on
    its ``PYTHONPATH``; a cluster gets both packages shipped as ``py_modules`` (their dependencies must be
    installed on every node, and data folders must exist there under the same path).
    """

    def __init__(self, address: str | None = None, cpus_per_run: int = 1, num_cpus: int | None = None,
                 init_kwargs: dict | None = None):
        self.ray = require_ray()
        self.address, self.cpus_per_run, self.num_cpus = address, cpus_per_run, num_cpus
        self.init_kwargs = dict(init_kwargs or {})
        self.name = f"ray {self.ray.__version__}"

    def _init(self) -> bool:
        ray = self.ray
        if ray.is_initialized():
            return False
        import slam
        import tdfields

        kw = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR}
        if self.address is None:
            root = str(Path(slam.__file__).resolve().parents[1])
            path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)
            kw.update(num_cpus=self.num_cpus, runtime_env={"env_vars": {"PYTHONPATH": path}})
        else:
            kw.update(address=self.address, runtime_env={"py_modules": [slam, tdfields]})
        kw.update(self.init_kwargs)
        try:
            ray.init(**kw)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            where = self.address or "a local Ray"
            raise SlamInputError(f"cannot start or reach {where}: {str(exc).strip().splitlines()[0]}") from None
        return True

    def run(self, specs: Sequence[RunSpec], on_result: Callable[[dict], None]) -> None:
        ray = self.ray
        started = self._init()
        try:
            # no automatic retry: a run that crashed its worker would most likely crash it again, and the
            # record (then a re-run of the sweep) is the better way to learn about it
            task = ray.remote(max_retries=0)(run_one)
            total = ray.cluster_resources().get("CPU")
            pending = {task.options(num_cpus=cpus_for(spec, self.cpus_per_run, total)).remote(spec): spec
                       for spec in specs}
            try:
                self._collect(pending, on_result, None)
            except BaseException:
                self._stop(pending, on_result, specs)
                raise
        finally:
            if started:
                ray.shutdown()


    def _collect(self, pending: dict, on_result, timeout: float | None) -> None:
        """Hand finished runs to ``on_result`` until none is pending (or ``timeout`` seconds have passed)."""
        ray = self.ray
        t_end = None if timeout is None else time.monotonic() + timeout
        while pending:
            left = None if t_end is None else max(t_end - time.monotonic(), 0.0)
            done, _ = ray.wait(list(pending), num_returns=1, timeout=left)
            if not done:
                return
            for ref in done:
                spec = pending.pop(ref)
                try:
                    rec = ray.get(ref)
                except Exception as exc:  # the worker died (out of memory, a signal, a lost node)
                    rec = failed_record(spec, exc)
                on_result(rec)

    def _stop(self, pending: dict, on_result, specs) -> None:
        """Ctrl-C of the sweep: the stop file is touched; running runs read it after each frame (partial outputs
        and a checkpoint, so the next sweep resumes them), runs not started yet return at once without starting,
        and all are waited for up to :data:`STOP_GRACE_S`; a second Ctrl-C, or the grace running out, kills what
        is left (those runs go on from their last periodic checkpoint)."""
        ray = self.ray
        # not ray.cancel(force=False): it raises KeyboardInterrupt inside a running task, which then writes nothing;
        # a queued task sees the stop file before its first frame and returns at once
        for spec in specs:
            if spec.stop_file:
                Path(spec.stop_file).touch()
        try:
            self._collect(pending, on_result, STOP_GRACE_S)
        except BaseException:
            pass
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)


#: seconds a stopped sweep waits for its running runs to finish their frame and write their checkpoints
STOP_GRACE_S = 120.0


# --------------------------------------------------------------------------------------------------- running
def execute(specs: Sequence[RunSpec], engine, out: str | Path | None = None,
            log: Callable[[str], None] | None = None, reuse: bool = True) -> dict:
    """Run the specs on ``engine`` and return the summary (also written to ``out`` when given).

    With ``reuse`` a finished run folder (same config) is not run again; without it every spec runs (a
    benchmark after a code change). ``summary.json`` / ``summary.md`` are rewritten after every run, so an
    interrupted sweep keeps what it did. Records are in plan order.
    """
    from slam.config import load_config

    log = log or (lambda s: print(s, file=sys.stderr))
    if len({s.run_dir for s in specs}) != len(specs):
        dup = next(s.run_dir for i, s in enumerate(specs) if any(s.run_dir == t.run_dir for t in specs[:i]))
        raise SlamInputError(f"two runs of the sweep would write to the same folder {dup}")
    records: dict[str, dict] = {}
    todo = []
    stop_file = None
    if out is not None:
        stop_file = Path(out) / ".stop"  # touched on Ctrl-C: the running runs stop after their frame
        Path(out).mkdir(parents=True, exist_ok=True)
        stop_file.unlink(missing_ok=True)
        specs = [dataclasses.replace(s, stop_file=str(stop_file)) for s in specs]
    for spec in specs:
        m = finished_metrics(spec.run_dir) if reuse else None
        if m is None:
            if reuse and interrupted(spec.run_dir):
                _check_same_config(spec, load_config(spec.preset, spec.config_overrides()).to_dict())
                spec = dataclasses.replace(spec, resume=True)
            todo.append(spec)
            continue
        _check_same_config(spec, load_config(spec.preset, spec.config_overrides()).to_dict())
        records[spec.run_dir] = {**m, **spec.identity(), "status": "ok", "reused": True}
    engine_name = getattr(engine, "name", type(engine).__name__)

    def current() -> dict:
        return summarize([records[s.run_dir] for s in specs if s.run_dir in records], engine_name)

    if records:
        log(f"{len(records)} of {len(specs)} runs already finished: reused")
    if any(s.resume for s in todo):
        log(f"{sum(s.resume for s in todo)} interrupted runs go on from their checkpoints")
    done = [0]

    def on_result(rec: dict) -> None:
        records[rec["run_dir"]] = rec
        done[0] += 1
        log(f"[{done[0]}/{len(todo)}] {_run_name(rec)}: {_short(rec)}")
        if out is not None:
            write_summary(out, current())

    if todo:
        engine.run(todo, on_result)
    summary = current()
    if out is not None:
        write_summary(out, summary)
    return summary


def _check_same_config(spec: RunSpec, planned: dict) -> None:
    """A finished folder is only reused for the same config (threads aside), else the numbers would lie."""
    import yaml

    path = Path(spec.run_dir) / "config.yaml"
    try:
        saved = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError):
        return
    a, b = flatten(saved), flatten(planned)
    diff = differing_keys(saved, planned, ignore=("threads",))
    if diff:
        k = diff[0]
        raise SlamInputError(f"{spec.run_dir} holds a finished run with another config ({k}: {a.get(k)!r} there, "
                             f"{b.get(k)!r} now); use another --out or remove that folder")


def _short(rec: dict) -> str:
    if rec["status"] != "ok":
        return f"FAILED {rec.get('error')}"
    ate = rec.get("ate_rmse_m")
    ate_s = "-" if ate is None else f"{100 * ate:.2f} cm"
    return f"ok, ATE RMSE {ate_s}, FPT {rec.get('fpt_s', float('nan')):.3f} s, {rec.get('wall_s', 0):.0f} s"


