"""Running a sweep: one run in its folder (reused when finished, resumed when interrupted), and :func:`execute`,
which runs the rest on an engine (:mod:`slam.sweep.engines`)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
import traceback
from pathlib import Path
from typing import Callable, Sequence

from slam.errors import SlamInputError

from slam.config.load import differing_keys, flatten
from slam.run.outputs import finished_metrics
from slam.sweep.plan import TRACEBACK_LINES, RunSpec, run_name
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
            "traceback": "\n".join(lines[-TRACEBACK_LINES:])}


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
        log(f"[{done[0]}/{len(todo)}] {run_name(rec)}: {_short(rec)}")
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

    from slam.config import config_from_dict

    path = Path(spec.run_dir) / "config.yaml"
    try:
        saved = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError):
        return
    try:  # a folder of an older version: its keys moved, the keys added since at the defaults it computed with
        saved = config_from_dict(saved, upgrade=True).to_dict()
    except SlamInputError:
        pass  # compared as written: the difference names the key
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

