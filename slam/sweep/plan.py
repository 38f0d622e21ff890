"""Planning a sweep: the request checked and every run's config resolved before any engine starts (:class:`RunSpec`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from slam.errors import SlamInputError

# keys the sweep sets itself (from its flags), so an override must not
_SWEEP_KEYS = ("representation", "seed", "threads", "data.path")
TRACEBACK_LINES = 12


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
        resume: go on from the folder's checkpoint (set by :func:`execute` for an interrupted run), with the
            run's own ``config.yaml`` (its threads too: a resumed run computes what it would have).
        stop_file: the run stops as on Ctrl-C (partial outputs, a checkpoint) once this file exists: how a sweep
            stopped by Ctrl-C leaves its running runs resumable.
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
    stop_file: str | None = None

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
    from slam.config import load_config, parse_overrides
    from slam.config.load import check_representation
    from slam.config.load import flatten

    if not configs:
        raise SlamInputError("give at least one preset with --config")
    if not representations:
        raise SlamInputError("give at least one representation with --representation")
    if seeds < 1:
        raise SlamInputError(f"--seeds must be >= 1, got {seeds}")
    if threads < 1:
        raise SlamInputError(f"--cpus-per-run must be >= 1, got {threads}")
    for rep in representations:
        check_representation(rep)
    if len(set(representations)) != len(representations):
        raise SlamInputError(f"a representation is given twice: {' '.join(representations)}")
    _refuse_sweep_keys(flatten(parse_overrides(list(overrides))))

    out = Path(out).expanduser().resolve()
    entries = _entries(configs, data)

    specs: list[RunSpec] = []
    checked: set = set()
    names: dict[str, str] = {}
    for preset, d in entries:
        for rep in representations:
            probe = RunSpec(preset, d, preset, rep, 0, tuple(overrides), "", mesh, threads)
            cfg = load_config(preset, probe.config_overrides())
            if check_data and (preset, d) not in checked:
                from slam.engine.setup import load_data

                load_data(cfg)
                checked.add((preset, d))
        label, folder = _label_and_folder(cfg.name, preset, d, entries, names)
        for rep in representations:
            for seed in range(seeds):
                specs.append(RunSpec(preset, d, label, rep, seed, tuple(overrides),
                                     str(out / f"{folder}-{rep}-s{seed}"), mesh, threads))
    return specs


def _refuse_sweep_keys(flat: dict) -> None:
    """An override (``flat``: dotted keys) must not set a key the sweep sets from its own flags."""
    for key in _SWEEP_KEYS:
        if key in flat:
            flag = {"representation": "--representation", "seed": "--seeds", "threads": "--cpus-per-run",
                    "data.path": "--config PRESET=DATA"}[key]
            raise SlamInputError(f"override '{key}' is set by the sweep itself; use {flag}")


def _entries(configs: Sequence[str], data: str | None) -> list[tuple[str, str | None]]:
    """``(preset, data folder)`` per ``--config`` item (``data`` for one without its own folder); a YAML path and
    the data folder are made absolute."""
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
    return entries


def _label_and_folder(cfg_name: str, preset: str, d: str | None, entries: list,
                      names: dict[str, str]) -> tuple[str, str]:
    """The summary label and the run folders' stem of one entry (``<name>``, or ``<name>@<data folder>`` for a
    preset given with several data folders); ``names`` (stem -> ``preset=data``, updated here) refuses two
    entries that would share run folders."""
    name = _slug(cfg_name)
    same_preset = [e for e in entries if e[0] == preset]
    label = cfg_name if len(same_preset) == 1 or d is None else f"{cfg_name}@{Path(d).name}"
    folder = name if label == cfg_name else f"{name}@{_slug(Path(d).name)}"
    if folder in names and names[folder] != f"{preset}={d}":
        raise SlamInputError(f"presets {names[folder]} and {preset}={d} would share the run folders {folder}-*")
    names[folder] = f"{preset}={d}"
    return label, folder


def run_name(rec: dict) -> str:
    return f"{rec['label']} {rec['representation']} seed {rec['seed']}" + (f" {rec['tag']}" if rec.get("tag") else "")
