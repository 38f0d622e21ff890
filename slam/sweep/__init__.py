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

from slam.sweep.plan import RunSpec, plan, split_preset
from slam.sweep.engines import RayEngine, SerialEngine, cpus_for, require_ray
from slam.sweep.runs import execute, failed_record, finished_metrics, interrupted, run_one
from slam.sweep.summary import group_stats, summarize, summary_markdown, write_summary

__all__ = ["RunSpec", "plan", "split_preset", "RayEngine", "SerialEngine", "cpus_for", "execute", "failed_record",
           "finished_metrics", "interrupted", "require_ray", "run_one", "group_stats", "summarize",
           "summary_markdown", "write_summary"]
