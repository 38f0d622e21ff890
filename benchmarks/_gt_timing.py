"""How far the ground truth's clock decides a loop's error on a fast-turning TUM sequence (issue 54, "no false loop"),
for ``profile_targets.py --loops``.

A loop's error against the ground truth compares its relative pose with the motion capture's poses at the two
images' timestamps. On fr1_rpy the camera turns at 50-70 degrees a second where the loops are found, so every 10 ms
between the motion capture's clock and the images' exposure is 0.5-0.7 degrees of apparent error. :func:`analyse`
takes a finished run with loops on a TUM folder and

* fits the time offset ``delta`` that best matches the ground truth to the tracker's own short motions (the median
  rotation error of its ``span``-frame relative poses, the ground truth taken at ``t + delta``, on a grid), using no
  loop: the camera-to-motion-capture offset the tracker sees over the whole sequence;
* gives each accepted loop's error against the ground truth at offset 0 (what ``metrics.json`` reports), at
  ``delta``, and at offset 0 with the ground truth taken at the depth images' timestamps (a loop's pose comes from
  depth as much as from colour), with the angular speed at both frames.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


class Truth:
    """The ground truth ``[M, 8]`` TUM rows, interpolated at any time inside its span (linear position, slerp
    rotation: :func:`slam.data.association.poses_at`, as the TUM loader takes it at the images' times)."""

    def __init__(self, rows: np.ndarray):
        self.rows = rows[np.argsort(rows[:, 0])]

    def at(self, t: np.ndarray) -> np.ndarray:
        """``[K]`` seconds (inside the ground truth's span) -> ``[K, 4, 4]`` camera-to-world."""
        from slam.data.association import poses_at

        t = np.atleast_1d(np.asarray(t, np.float64))
        return poses_at(self.rows[:, 0], self.rows[:, 1:8], t, np.inf, interpolate=True)[0]

    def angular_speed_deg(self, t: float, half: float = 0.03) -> float:
        """Degrees a second of the rotation over ``[t - half, t + half]``."""
        from slam.core.pose import pose_gap

        a, b = self.at(np.array([t - half, t + half]))
        return pose_gap(a, b)[1] / (2 * half)


def relative_rotation_errors(est: np.ndarray, t: np.ndarray, truth: Truth, delta: float, span: int) -> np.ndarray:
    """Degrees between the estimate's relative rotation over ``span`` frames and the ground truth's at ``t +
    delta`` (``est [N, 4, 4]``, ``t [N]`` seconds), one per frame pair inside the ground truth's span."""
    from slam.core.pose import pose_gap

    lo, hi = truth.rows[0, 0], truth.rows[-1, 0]
    i = np.arange(len(t) - span)
    i = i[(t[i] + delta >= lo) & (t[i + span] + delta <= hi)]
    G = truth.at(t + delta) if len(i) else None
    return np.array([pose_gap(np.linalg.inv(est[a]) @ est[a + span], np.linalg.inv(G[a]) @ G[a + span])[1]
                     for a in i])


def fit_offset(est: np.ndarray, t: np.ndarray, truth: Truth, span: int = 5, grid_ms: float = 60.0,
               step_ms: float = 2.5) -> tuple[float, list[dict]]:
    """The time offset (seconds, added to the image timestamps) whose ground truth best fits the estimate's
    ``span``-frame rotations (smallest median error) on a grid of ``+-grid_ms`` in ``step_ms``; and the curve."""
    curve = []
    for ms in np.arange(-grid_ms, grid_ms + 1e-9, step_ms):
        e = relative_rotation_errors(est, t, truth, ms / 1000.0, span)
        curve.append({"offset_ms": round(float(ms), 2), "median_deg": float(np.median(e)) if len(e) else None})
    best = min((c for c in curve if c["median_deg"] is not None), key=lambda c: c["median_deg"])
    return best["offset_ms"] / 1000.0, curve


def loop_errors(loops: list[dict], t_rgb: np.ndarray, t_depth: np.ndarray, truth: Truth, delta: float) -> list[dict]:
    """Each accepted loop (``metrics.json``'s ``loops.accepted``) against the ground truth three ways: at the
    colour images' timestamps (offset 0, as ``metrics.json``), at ``delta``, and at the depth images'."""
    from slam.core.pose import pose_gap

    out = []
    for lp in loops:
        q, c, rel = lp["query"], lp["match"], np.asarray(lp["relative_pose"])
        row = {"query": q, "match": c, "angular_speed_deg_s": [round(truth.angular_speed_deg(t_rgb[q]), 1),
                                                               round(truth.angular_speed_deg(t_rgb[c]), 1)]}
        for name, tq, tc in (("offset_0", t_rgb[q], t_rgb[c]), ("fitted_offset", t_rgb[q] + delta, t_rgb[c] + delta),
                             ("depth_time", t_depth[q], t_depth[c])):
            A, B = truth.at(np.array([tc, tq]))
            dt, dr = pose_gap(np.linalg.inv(A) @ B, rel)
            row[name] = {"m": round(dt, 4), "deg": round(dr, 3)}
        out.append(row)
    return out


def analyse(run: Path, data: Path, span: int = 5) -> dict:
    """The fitted offset and the loops' errors of one finished run with loops (its ``trajectory_odometry.txt`` and
    ``metrics.json``) on the TUM folder ``data`` (its ``groundtruth.txt``; depth images named by their time)."""
    from slam.data.loader import load_dataset
    from slam.data.tum_format import read_tum_poses
    from slam.eval.trajectory import read_tum_trajectory

    ds = load_dataset(data, "tum")
    t_rgb = np.asarray(ds.timestamps, np.float64)
    t_depth = np.array([float(p.stem) for p in ds.depth_paths], np.float64)
    _, est = read_tum_trajectory(run / "trajectory_odometry.txt")
    truth = Truth(read_tum_poses(data / "groundtruth.txt"))
    delta, curve = fit_offset(est, t_rgb, truth, span)
    m = json.loads((run / "metrics.json").read_text())
    return {"fitted_offset_ms": round(delta * 1000, 2), "span": span, "curve": curve,
            "loops": loop_errors((m.get("loops") or {}).get("accepted", []), t_rgb, t_depth, truth, delta)}


def tum_folder(args: list[str]) -> Path | None:
    """The ``--data=DIR`` of ``lrslam run`` arguments when it is a TUM folder with ground truth, else None."""
    for a in args:
        if a.startswith("--data="):
            d = Path(a.split("=", 1)[1])
            return d if (d / "groundtruth.txt").is_file() and (d / "depth.txt").is_file() else None
    return None


def worst(timings: list[dict], key: str) -> list[float] | None:
    """``[metres, degrees]``: the largest loop errors (each on its own) over runs' :func:`analyse` results, at
    ``key`` ("offset_0", "fitted_offset", "depth_time"); None without a loop."""
    errs = [lp[key] for t in timings for lp in t["loops"]]
    return [max(e["m"] for e in errs), max(e["deg"] for e in errs)] if errs else None
