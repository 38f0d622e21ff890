"""Sweeps: every (preset, representation, seed) combination as one run in its own folder, then a summary.

Three steps, kept apart so each can be used (and tested) alone:

* :func:`plan` checks the request and resolves every run's config in this process, so a bad preset, key,
  representation or data folder fails before any engine starts, and returns :class:`RunSpec` s;
* an engine runs them: :class:`RayEngine` (one Ray task per run, a local Ray or a cluster) or
  :class:`SerialEngine` (this process, one after another); :func:`execute` skips the finished ones first;
* :func:`summarize` / :func:`summary_markdown` turn the run records into ``summary.json`` and ``summary.md``
  (mean ± std per preset and representation), with no engine involved.

A run's record is its ``metrics.json`` plus ``preset``, ``data``, ``representation``, ``seed``, ``overrides``,
``run_dir`` and ``status`` (``ok`` / ``failed``); a failed run carries ``error`` (one line) and ``traceback``
(its last frames) instead of metrics. A run folder whose ``metrics.json`` exists and is not marked
``"partial": true`` is finished, and a repeated sweep reuses it (``"reused": true``) instead of running it again;
an interrupted run (partial, no error, a checkpoint) goes on from its checkpoint (``resumed_from`` in its record).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import statistics
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

from slam.errors import SlamInputError

# keys the sweep sets itself (from its flags), so an override must not
_SWEEP_KEYS = ("representation", "seed", "threads", "data.path")
_TRACEBACK_LINES = 12


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep.

    Attributes:
        preset: preset name or YAML path, as given; ``data``: absolute data folder or None (the preset's).
        label: the preset as the summary groups it (``preset`` or ``preset@<data folder name>``).
        representation, seed: the run's; ``overrides``: the user's ``key=value`` overrides.
        run_dir: absolute output folder; ``mesh``: extract the mesh; ``threads``: torch threads of the run.
        backend: tdfields kernel backend for the run (``auto`` / ``torch`` / ``numba``), None = leave as is.
        tag: free text naming the run beyond preset, representation and seed (e.g. a repeat), empty by default.
        progress: show the run's progress bar (only sensible for runs in this process).
        resume: go on from the folder's checkpoint (set by :func:`execute` for an interrupted run).
    """

    preset: str
    data: str | None
    label: str
    representation: str
    seed: int
    overrides: tuple[str, ...]
    run_dir: str
    mesh: bool = True
    threads: int = 1
    backend: str | None = None
    tag: str = ""
    progress: bool = False
    resume: bool = False

    def config_overrides(self) -> list[str]:
        over = [f"representation={self.representation}", f"seed={self.seed}", f"threads={self.threads}",
                *self.overrides]
        if self.data is not None:
            over.append(f"data.path={self.data}")
        return over

    def identity(self) -> dict:
        """The fields a record repeats so it can be read without its spec."""
        d = {"preset": self.preset, "data": self.data, "label": self.label, "representation": self.representation,
             "seed": self.seed, "overrides": list(self.overrides), "run_dir": self.run_dir}
        if self.backend is not None:
            d["backend"] = self.backend
        if self.tag:
            d["tag"] = self.tag
        return d


# --------------------------------------------------------------------------------------------------- planning
def split_preset(item: str) -> tuple[str, str | None]:
    """``PRESET`` or ``PRESET=DATA`` -> (preset, data or None)."""
    preset, sep, data = item.partition("=")
    return preset, (data if sep else None)


def _slug(text: str) -> str:
    return text.replace("/", "_").replace("\\", "_").replace(os.sep, "_")


def plan(configs: Sequence[str], representations: Sequence[str], seeds: int, out: str | Path,
         overrides: Sequence[str] = (), threads: int = 1, mesh: bool = True, data: str | None = None,
         check_data: bool = True) -> list[RunSpec]:
    """Check a sweep request and return its runs, preset-major, then representation, then seed.

    Args:
        configs: presets (names or YAML paths), each optionally ``PRESET=DATA`` with its data folder.
        representations: names from :data:`slam.config.REPRESENTATIONS`.
        seeds: runs per combination, seeds ``0 .. seeds-1``.
        out: the sweep folder; run ``i`` goes to ``out/<preset>-<representation>-s<seed>``.
        overrides: ``key=value`` config overrides applied to every run.
        threads: torch threads per run (the CPUs each run is given).
        data: data folder for the presets given without one.
        check_data: open each distinct dataset once here (fails early on a missing or wrong folder, and
            writes the bundled synthetic sequence once instead of in every worker at the same time).

    Raises:
        SlamInputError: no presets or representations, ``seeds < 1``, an unknown preset, representation or
            config key, an override of a key the sweep sets, a data folder that is missing or does not match.
    """
    from slam.config import REPRESENTATIONS, load_config, parse_overrides

    if not configs:
        raise SlamInputError("give at least one preset with --config")
    if not representations:
        raise SlamInputError("give at least one representation with --representation")
    if seeds < 1:
        raise SlamInputError(f"--seeds must be >= 1, got {seeds}")
    if threads < 1:
        raise SlamInputError(f"--cpus-per-run must be >= 1, got {threads}")
    for rep in representations:
        if rep not in REPRESENTATIONS:
            raise SlamInputError(f"unknown representation '{rep}'; choose from {', '.join(REPRESENTATIONS)}")
    if len(set(representations)) != len(representations):
        raise SlamInputError(f"a representation is given twice: {' '.join(representations)}")
    flat = _flatten(parse_overrides(list(overrides)))
    for key in _SWEEP_KEYS:
        if key in flat:
            flag = {"representation": "--representation", "seed": "--seeds", "threads": "--cpus-per-run",
                    "data.path": "--config PRESET=DATA"}[key]
            raise SlamInputError(f"override '{key}' is set by the sweep itself; use {flag}")

    out = Path(out).expanduser().resolve()
    entries = []
    for item in configs:
        preset, d = split_preset(item)
        if not preset:
            raise SlamInputError(f"--config '{item}': empty preset name")
        if preset.endswith((".yaml", ".yml")) and Path(preset).expanduser().is_file():
            # workers may not share this process's working directory
            preset = str(Path(preset).expanduser().resolve())
        d = d if d is not None else data
        if d is not None:
            p = Path(d).expanduser()
            if not p.exists():
                raise SlamInputError(f"data folder not found: {p} (for preset {preset})")
            d = str(p.resolve())
        entries.append((preset, d))
    if len(set(entries)) != len(entries):
        raise SlamInputError(f"a preset is given twice with the same data: {' '.join(configs)}")

    specs: list[RunSpec] = []
    checked: set = set()
    names: dict[str, str] = {}
    for preset, d in entries:
        for rep in representations:
            probe = RunSpec(preset, d, preset, rep, 0, tuple(overrides), "", mesh, threads)
            cfg = load_config(preset, probe.config_overrides())
            if check_data and (preset, d) not in checked:
                from slam.system import load_data

                load_data(cfg)
                checked.add((preset, d))
        name = _slug(cfg.name)
        same_preset = [e for e in entries if e[0] == preset]
        label = cfg.name if len(same_preset) == 1 or d is None else f"{cfg.name}@{Path(d).name}"
        folder = name if label == cfg.name else f"{name}@{_slug(Path(d).name)}"
        if folder in names and names[folder] != f"{preset}={d}":
            raise SlamInputError(f"presets {names[folder]} and {preset}={d} would share the run folders {folder}-*")
        names[folder] = f"{preset}={d}"
        for rep in representations:
            for seed in range(seeds):
                specs.append(RunSpec(preset, d, label, rep, seed, tuple(overrides),
                                     str(out / f"{folder}-{rep}-s{seed}"), mesh, threads))
    return specs


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


# --------------------------------------------------------------------------------------------------- one run
def finished_metrics(run_dir: str | Path) -> dict | None:
    """The metrics of a finished run in ``run_dir``, or None (no ``metrics.json``, unreadable, or partial)."""
    path = Path(run_dir) / "metrics.json"
    try:
        m = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("partial"):
        return None
    return m


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
    from slam.runner import run_to_folder

    t0 = time.perf_counter()
    try:
        with contextlib.ExitStack() as stack:
            if spec.backend is not None:
                from tdfields import kernels

                stack.enter_context(kernels.use_backend(spec.backend))
            cfg = load_config(spec.preset, spec.config_overrides())
            metrics = run_to_folder(cfg, spec.run_dir, progress=spec.progress, mesh=spec.mesh, resume=spec.resume)
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
            on_result(run_one(spec))


def require_ray():
    """Import and return ``ray``; SlamInputError naming the install command if it is missing."""
    try:
        import ray
    except ImportError:
        from slam._deps import install_command

        raise SlamInputError(f"lrslam sweep runs on Ray, which is not installed; install the sweep extra: "
                             f"{install_command('sweep')} (or: python3 -m pip install \"ray>=2.9\")") from None
    return ray


class RayEngine:
    """One Ray task per run (``num_cpus = cpus_per_run``), results handled as they finish.

    Args:
        address: a Ray cluster's address (``ray.init(address=...)``); None starts a local Ray for the sweep
            and stops it afterwards. A Ray already initialised in this process is used as it is.
        cpus_per_run: CPUs Ray reserves for each run (also its torch thread count, see :func:`plan`).
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
            task = ray.remote(num_cpus=self.cpus_per_run, max_retries=0)(run_one)
            pending = {task.remote(spec): spec for spec in specs}
            try:
                while pending:
                    done, _ = ray.wait(list(pending), num_returns=1)
                    for ref in done:
                        spec = pending.pop(ref)
                        try:
                            rec = ray.get(ref)
                        except Exception as exc:  # the worker died (out of memory, a signal, a lost node)
                            rec = failed_record(spec, exc)
                        on_result(rec)
            except BaseException:
                for ref in pending:
                    ray.cancel(ref, force=True)
                raise
        finally:
            if started:
                ray.shutdown()


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
    a, b = _flatten(saved), _flatten(planned)
    diff = sorted(k for k in set(a) | set(b) if k != "threads" and a.get(k) != b.get(k))
    if diff:
        k = diff[0]
        raise SlamInputError(f"{spec.run_dir} holds a finished run with another config ({k}: {a.get(k)!r} there, "
                             f"{b.get(k)!r} now); use another --out or remove that folder")


def _run_name(rec: dict) -> str:
    return f"{rec['label']} {rec['representation']} seed {rec['seed']}" + (f" {rec['tag']}" if rec.get("tag") else "")


def _short(rec: dict) -> str:
    if rec["status"] != "ok":
        return f"FAILED {rec.get('error')}"
    ate = rec.get("ate_rmse_m")
    ate_s = "-" if ate is None else f"{100 * ate:.2f} cm"
    return f"ok, ATE RMSE {ate_s}, FPT {rec.get('fpt_s', float('nan')):.3f} s, {rec.get('wall_s', 0):.0f} s"


# --------------------------------------------------------------------------------------------------- summary
def summarize(records: Iterable[dict], engine: str) -> dict:
    """``{"engine", "date", "runs": [...], "groups": [...]}``: the records and per-group statistics."""
    runs = list(records)
    return {"engine": engine, "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "runs": runs,
            "groups": group_stats(runs)}


def _mean_std(values: list[float]) -> tuple[float | None, float | None]:
    vals = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not vals:
        return None, None
    return statistics.fmean(vals), (statistics.stdev(vals) if len(vals) > 1 else None)


def group_stats(runs: Sequence[dict]) -> list[dict]:
    """Per (label, representation), in first-seen order: run counts and mean / sample std of ATE RMSE (m),
    FPT (s) and total parameters over the runs that finished."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault((r["label"], r["representation"]), []).append(r)
    out = []
    for (label, rep), rs in groups.items():
        ok = [r for r in rs if r.get("status") == "ok"]
        g = {"label": label, "representation": rep, "runs": len(rs), "ok": len(ok), "failed": len(rs) - len(ok),
             "seeds": [r["seed"] for r in ok]}
        for key, get in (("ate_rmse_m", lambda r: r.get("ate_rmse_m")), ("fpt_s", lambda r: r.get("fpt_s")),
                         ("parameters", lambda r: (r.get("parameters") or {}).get("total"))):
            g[f"{key}_mean"], g[f"{key}_std"] = _mean_std([get(r) for r in ok])
        out.append(g)
    return out


def _pm(mean, std, scale=1.0, digits=3) -> str:
    if mean is None:
        return "-"
    s = f"{mean * scale:.{digits}f}"
    return s if std is None else f"{s} ± {std * scale:.{digits}f}"


def summary_markdown(summary: dict) -> str:
    """The summary as a markdown table (mean ± sample std over each group's finished runs), failures listed."""
    lines = [f"# Sweep summary ({summary['date']}, {summary['engine']})", "",
             "| preset | representation | runs (ok / all) | ATE RMSE (cm) | FPT (s) | parameters |",
             "|---|---|---|---|---|---|"]
    for g in summary["groups"]:
        p_mean, p_std = g["parameters_mean"], g["parameters_std"]
        params = "-" if p_mean is None else (f"{p_mean:,.0f}" if not p_std else f"{p_mean:,.0f} ± {p_std:,.0f}")
        lines.append(f"| {g['label']} | {g['representation']} | {g['ok']} / {g['runs']} | "
                     f"{_pm(g['ate_rmse_m_mean'], g['ate_rmse_m_std'], 100.0)} | "
                     f"{_pm(g['fpt_s_mean'], g['fpt_s_std'])} | {params} |")
    lines += ["", "Mean ± sample standard deviation over the runs that finished (one run: the value alone)."]
    failed = [r for r in summary["runs"] if r.get("status") != "ok"]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- {_run_name(r)} (`{r['run_dir']}`): {r.get('error')}" for r in failed]
    return "\n".join(lines) + "\n"


def write_summary(out: str | Path, summary: dict) -> None:
    """``summary.json`` and ``summary.md`` in ``out``, each written to a temporary name and renamed."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (("summary.json", json.dumps(summary, indent=2, default=str)),
                       ("summary.md", summary_markdown(summary))):
        tmp = out / f".{name}.tmp"
        tmp.write_text(text)
        os.replace(tmp, out / name)
