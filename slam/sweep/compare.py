"""Is B really better than A? Two sets of seeded runs compared per configuration, with the seeds' spread.

A difference of means smaller than the seeds' spread decides nothing: a 3-seed screen on the fast TUM window once
pointed one way (2.20 against 2.24 cm) and the same settings over 5 seeds the other (2.35 against 2.25). This module
puts a confidence interval on every difference so that a table says which ones are resolved.

Inputs are the files the project's sweeps write: ``slam_compare.json`` (``benchmarks/slam_compare.py``) or
``summary.json`` (``lrslam sweep``), or a folder holding one. Runs are grouped by configuration (preset, data
folder name, representation, backend) and compared on ATE RMSE in cm:

* every seed in both: a **paired** comparison, ``d_s = B_s - A_s``, mean ± ``t * sd(d) / sqrt(n)`` (a run is
  deterministic for its seed, so identical code gives ``d = 0`` exactly) -- on one machine only: where both files
  carry a float fingerprint (:func:`slam.engine.runtime.float_fingerprint`, in ``slam_compare.json``'s stamp) and
  they differ, seed ``s`` is not the same run on both sides, and the comparison is unpaired;
* otherwise **Welch**'s: ``mean(B) - mean(A)`` ± ``t * sqrt(s_A^2 / n_A + s_B^2 / n_B)`` with Welch-Satterthwaite
  degrees of freedom;

``t`` is Student's two-sided 95 % quantile. The verdict is ``identical`` when every paired seed is equal,
``B lower`` / ``B higher`` when the interval excludes 0, else ``unresolved``, with the seeds per side a difference
of that size would need if the spread stays as measured (the smallest ``n`` with ``t(n - 1) * sd / sqrt(n) < |d|``,
``sd`` of the paired differences or, unpaired, ``sqrt(2)`` times the pooled per-run spread; ``None`` beyond 100).
The table also counts the seeds on which B is lower: one diverged seed widens the interval of a difference that
every seed shows.
"""

from __future__ import annotations

import json
import math
import statistics
from dataclasses import dataclass
from pathlib import Path

from slam.errors import SlamInputError

_FILES = ("slam_compare.json", "summary.json")


def _source(path: str | Path) -> Path:
    p = Path(path)
    if p.is_dir():
        for name in _FILES:
            if (p / name).is_file():
                return p / name
        raise SlamInputError(f"{p}: no {' or '.join(_FILES)} in this folder")
    if not p.is_file():
        raise SlamInputError(f"{p}: no such file or folder")
    return p


def load_runs(path: str | Path) -> dict[tuple, dict[int, float]]:
    """``{(config, representation, backend): {seed: ATE RMSE cm}}`` of the finished runs in a result file.

    Args:
        path: a ``slam_compare.json`` or ``summary.json``, or a folder with one of them.

    Raises:
        SlamInputError: no such file, not JSON, not one of the two layouts, or no finished run with an ATE.
    """
    src = _source(path)
    try:
        data = json.loads(src.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SlamInputError(f"{src}: not a readable JSON file ({exc})") from None
    runs = data.get("runs") if isinstance(data, dict) else None
    if not isinstance(runs, list):
        raise SlamInputError(f"{src}: no 'runs' list (expected slam_compare.json or a sweep's summary.json)")
    out: dict[tuple, dict[int, float]] = {}
    for i, r in enumerate(runs):
        if not isinstance(r, dict) or "representation" not in r or "seed" not in r:
            raise SlamInputError(f"{src}: run {i} has no representation or seed")
        # one name for a configuration in both formats: "preset (data folder)", so a sweep compares with a benchmark
        data_name = Path(r["data"]).name if r.get("data") else None
        if "ate_rmse_cm" in r:  # slam_compare.json
            ate = r["ate_rmse_cm"]
            preset = r.get("sequence")
            backend = r.get("backend", "auto")
        else:  # a sweep's summary.json: metres, and failed runs recorded beside the finished ones
            if r.get("status", "ok") != "ok" or r.get("ate_rmse_m") is None:
                continue
            ate = 100.0 * float(r["ate_rmse_m"])
            preset = r.get("preset") or r.get("label")
            backend = "auto"
        config = f"{preset} ({data_name})" if data_name else str(preset)
        if ate is None or not math.isfinite(float(ate)):
            continue
        group = out.setdefault((config, r["representation"], backend), {})
        group.setdefault(int(r["seed"]), float(ate))  # repeats of a seed give the same ATE: keep the first
    if not out:
        raise SlamInputError(f"{src}: no finished run with an ATE to compare")
    return out


def load_fingerprint(path: str | Path) -> str | None:
    """The float fingerprint of the machine a result file's runs were made on (``stamp.float_fingerprint`` of a
    ``slam_compare.json``, else the runs' own, from their ``metrics.json``), None where none was recorded;
    ``"mixed: ..."`` when the runs of one file came from machines that round differently."""
    data = json.loads(_source(path).read_text())
    if not isinstance(data, dict):
        return None
    stamp = data.get("stamp") if isinstance(data.get("stamp"), dict) else {}
    if stamp.get("float_fingerprint"):
        return stamp["float_fingerprint"]
    found = {r.get("float_fingerprint") for r in data.get("runs") or [] if isinstance(r, dict)} - {None}
    return None if not found else (found.pop() if len(found) == 1 else "mixed: " + " ".join(sorted(found)))


def _t95(df: float) -> float:
    from scipy.stats import t

    return float(t.ppf(0.975, df))


@dataclass
class Difference:
    """B minus A for one configuration (ATE RMSE, cm); ``half_width`` is the 95 % interval's half width
    (``None`` with fewer than two runs a side), ``seeds_needed`` what :func:`seeds_needed` estimates (``None`` when
    resolved or not estimable)."""

    config: str
    representation: str
    backend: str
    method: str
    a: list[float]
    b: list[float]
    diff: float
    half_width: float | None
    verdict: str
    seeds_needed: int | None

    @property
    def mean_a(self) -> float:
        return statistics.fmean(self.a)

    @property
    def mean_b(self) -> float:
        return statistics.fmean(self.b)


def compare_values(a: dict[int, float], b: dict[int, float],
                   pair: bool = True) -> tuple[str, float, float | None, float | None]:
    """``(method, diff, half_width, sd)`` of B - A for one configuration's per-seed values (see the module);
    ``pair=False``: unpaired even with the same seeds (runs from two machines)."""
    if pair and set(a) == set(b) and len(a) >= 2:
        d = [b[s] - a[s] for s in sorted(a)]
        sd = statistics.stdev(d)
        return "paired", statistics.fmean(d), _t95(len(d) - 1) * sd / math.sqrt(len(d)), sd
    va, vb = list(a.values()), list(b.values())
    diff = statistics.fmean(vb) - statistics.fmean(va)
    if len(va) < 2 or len(vb) < 2:
        return "welch", diff, None, None
    qa, qb = statistics.variance(va) / len(va), statistics.variance(vb) / len(vb)
    se2 = qa + qb
    if se2 == 0.0:
        return "welch", diff, 0.0, 0.0
    df = se2 ** 2 / (qa ** 2 / (len(va) - 1) + qb ** 2 / (len(vb) - 1))
    pooled = math.sqrt((statistics.variance(va) + statistics.variance(vb)) / 2.0)
    return "welch", diff, _t95(df) * math.sqrt(se2), pooled


def seeds_needed(diff: float, sd: float | None, paired: bool, limit: int = 100) -> int | None:
    """Seeds per side at which a difference ``diff`` would be resolved if the spread ``sd`` stayed as measured (see
    the module); ``None`` when ``diff`` is 0, ``sd`` unknown, or more than ``limit`` would be needed."""
    if not diff or not sd:
        return None
    spread = sd if paired else math.sqrt(2.0) * sd
    for n in range(2, limit + 1):
        if _t95(n - 1) * spread / math.sqrt(n) < abs(diff):
            return n
    return None


def compare(a_path: str | Path, b_path: str | Path | None = None,
            representations: tuple[str, str] | None = None) -> list[Difference]:
    """B - A for every configuration present in both result files, in A's order.

    Args:
        a_path, b_path: result files or folders; ``b_path`` defaults to ``a_path`` (with ``representations``).
        representations: ``(ref, cand)``: compare representation ``cand`` in B against ``ref`` in A on the same
            configuration (e.g. ``("eslam", "lrslam")``: is the low-rank scene as accurate as tri-planes at the
            same budget?). ``Difference.representation`` then reads ``"cand - ref"``.

    Raises:
        SlamInputError: a file that :func:`load_runs` refuses, or no configuration in common.
    """
    b_path = a_path if b_path is None else b_path
    a, b = load_runs(a_path), load_runs(b_path)
    pair, _ = machines(a_path, b_path)
    if representations is None:
        pairs = [(k, k, k[1]) for k in a if k in b]
    else:
        ref, cand = representations
        pairs = [(k, (k[0], cand, k[2]), f"{cand} - {ref}") for k in a if k[1] == ref and (k[0], cand, k[2]) in b]
    if not pairs:
        what = "" if representations is None else f" for {representations[1]} against {representations[0]}"
        raise SlamInputError(f"{a_path} and {b_path} have no configuration in common{what}; A has "
                             f"{sorted(set(a))}, B has {sorted(set(b))}")
    out = []
    for ka, kb, label in pairs:
        method, diff, hw, sd = compare_values(a[ka], b[kb], pair)
        if not pair:
            method = "welch, two machines"
        if method == "paired" and all(a[ka][k] == b[kb][k] for k in a[ka]):
            verdict, needed = "identical", None  # every seed equal: the same runs, not an unresolved difference
        elif hw is None:
            verdict, needed = "unresolved (one run a side)", None
        elif abs(diff) > hw:
            verdict, needed = ("B lower" if diff < 0 else "B higher"), None
        else:
            verdict, needed = "unresolved", seeds_needed(diff, sd, paired=method == "paired")
        out.append(Difference(ka[0], label, ka[2], method, [a[ka][s] for s in sorted(a[ka])],
                              [b[kb][s] for s in sorted(b[kb])], diff, hw, verdict, needed))
    return out


def machines(a_path: str | Path, b_path: str | Path) -> tuple[bool, str]:
    """``(pair, note)``: whether A's and B's runs may be paired by seed (not when both carry float fingerprints
    and they differ; see the module), and one line saying why, empty when both carry the same fingerprint or A and
    B are the same file."""
    if Path(a_path) == Path(b_path):
        return True, ""
    fa, fb = load_fingerprint(a_path), load_fingerprint(b_path)
    if fa and fb:
        return fa == fb, "" if fa == fb else (
            f"A and B ran on machines that round differently (float fingerprints {fa} / {fb}): a seed is not the "
            "same run on both, so the comparison is unpaired (Welch's).")
    return True, ("A or B records no float fingerprint: pairing by seed assumes both ran on one machine (a seed "
                  "repeats a run exactly only there).")


def markdown(diffs: list[Difference], a_label: str, b_label: str, note: str = "") -> str:
    """The comparison as a markdown table (ATE RMSE cm; B - A with its 95 % interval); ``note``: a line above it."""
    lines = [f"A = `{a_label}`, B = `{b_label}`; ATE RMSE in cm, B - A with its 95 % interval (Student t).", "",
             *([note, ""] if note else []),
             "| configuration | representation | seeds A / B | A mean | B mean | B - A | method | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for d in diffs:
        ci = "" if d.half_width is None else f" ± {d.half_width:.2f}"
        method = d.method
        if d.method == "paired":  # a heavy tail (one diverged seed) widens the interval; the count shows it
            method += f", B lower on {sum(b < a for a, b in zip(d.a, d.b))} of {len(d.a)}"
        verdict = d.verdict
        if d.verdict == "unresolved":
            verdict += (f" (~{d.seeds_needed} seeds would resolve a difference this size)" if d.seeds_needed
                        else " (more than 100 seeds for a difference this size)")
        rep = d.representation + ("" if d.backend == "auto" else f" ({d.backend})")
        lines.append(f"| {d.config} | {rep} | {len(d.a)} / {len(d.b)} | {d.mean_a:.2f} | {d.mean_b:.2f} | "
                     f"{d.diff:+.2f}{ci} | {method} | {verdict} |")
    return "\n".join(lines) + "\n"
