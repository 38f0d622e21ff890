"""The engines that run a sweep's runs: :class:`SerialEngine` (this process, one after another) and
:class:`RayEngine` (one Ray task per run); each hands every run's record to a callback as it finishes."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Callable, Sequence

from slam.errors import SlamInputError
from slam.sweep.plan import RunSpec
from slam.sweep.runs import failed_record, run_one


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
