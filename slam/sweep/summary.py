"""A sweep's summary: mean ± std per (preset, representation), as ``summary.json`` and ``summary.md``; no engine
involved."""

from __future__ import annotations

import json
import math
import statistics
import time
from pathlib import Path

from slam.files import atomic_write_text
from typing import Iterable, Sequence

from slam.sweep.plan import run_name


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
        lines += [f"- {run_name(r)} (`{r['run_dir']}`): {r.get('error')}" for r in failed]
    return "\n".join(lines) + "\n"


def write_summary(out: str | Path, summary: dict) -> None:
    """``summary.json`` and ``summary.md`` in ``out``, each written durably (:mod:`slam.files`)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (("summary.json", json.dumps(summary, indent=2, default=str)),
                       ("summary.md", summary_markdown(summary))):
        atomic_write_text(out / name, text, "sweep summary")
