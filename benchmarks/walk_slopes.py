"""How the SLAM scene's size grows with the box, and whether the long walk's runs grew as predicted (issue 24).

For each representation it builds the scene of ``synthetic/walk`` at the box its run starts with (the same bound
rule and first frames, ``slam.engine.system.SLAM``) and grows it the way the run does (``slam.model.box_resize``: whole
coarse cells, every field resized) in three shapes, one cell per step:

* ``corridor``: one side (+x) grows, as the walk does;
* ``flat``: +x and +y grow together (a floor of offices);
* ``building``: +x, +y and +z grow together.

Per shape it fits ``parameters = a + b L + c L^2`` in the growing side ``L`` (metres) and the log-log slope over
the last half of the steps; the memory-growth benchmark (``benchmarks/memory_growth.py``) measures the exponents of
the kinds themselves in a growing cube: CP and Six-axis 1, tri-plane and VM 2. It then reads the walk study's per-frame
series (``--walk``, written by ``benchmarks/walk_study.py``) and compares every growth the runs made with the
predicted increments of one cell on each side.

    python benchmarks/walk_slopes.py --walk benchmarks/results/walk/walk_study.json --out benchmarks/results/walk
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SHAPES = {"corridor": ("x",), "flat": ("x", "y"), "building": ("x", "y", "z")}


def scene_at_start(representation: str):
    """The scene (``SceneModel``) a ``synthetic/walk`` run starts with, its coarse growth cell (m) and the config."""
    from slam.config import load_config
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic/walk", [f"representation={representation}", "data.max_frames=12"])
    s = SLAM(cfg, load_data(cfg))
    s.close()
    return s.scene, s.growth.cell, cfg


def grow_series(scene, cell: float, axes: tuple[str, ...], steps: int) -> list[dict]:
    """Grow ``scene`` in place by one ``cell`` on the ``+axes`` sides per step: ``[{L, parameters, field_bytes}]``
    with ``L`` the extent of the first growing axis (m)."""
    from slam.model.box_resize import apply_growth, plan_growth
    from slam.model.scene import scene_size

    a0 = "xyz".index(axes[0])
    out = []
    for i in range(steps + 1):
        if i:
            upper = tuple(cell if "xyz"[a] in axes else 0.0 for a in range(3))
            apply_growth(scene, plan_growth(scene, (0.0, 0.0, 0.0), upper))
        p, b = scene_size(scene)
        box = scene.aabb.detach().double()
        out.append({"L": float(box[a0, 1] - box[a0, 0]), "parameters": p, "field_bytes": b})
    return out


def fit(series: list[dict]) -> dict:
    """Quadratic least squares ``a + b L + c L^2`` and the log-log slope of the last half (parameters)."""
    import numpy as np

    L = np.array([r["L"] for r in series])
    P = np.array([r["parameters"] for r in series], dtype=float)
    c, b, a = np.polyfit(L, P, 2)
    half = len(L) // 2
    slope = float(np.polyfit(np.log(L[half:]), np.log(P[half:] - 0), 1)[0])
    increments = sorted({int(d) for d in np.diff(P)})
    return {"a": float(a), "b_per_m": float(b), "c_per_m2": float(c),
            "quadratic_share_at_end": float(c * L[-1] ** 2 / (P[-1] - a)) if P[-1] != a else 0.0,
            "loglog_slope_last_half": slope, "increments_per_cell": increments}


def walk_increments(walk: dict, name: str) -> list[int]:
    """The parameter increments of every growth in the walk study's seed-0 series of ``name``."""
    pts = walk["series"].get(name) or []
    return [b["parameters"] - a["parameters"] for a, b in zip(pts, pts[1:]) if b["parameters"] != a["parameters"]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=24, help="cells grown per shape")
    ap.add_argument("--walk", type=Path, help="walk_study.json whose growths to check")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    from _stamp import stamp

    walk = json.loads(args.walk.read_text()) if args.walk else None
    res = {"stamp": stamp(), "steps": args.steps, "representations": {}}
    for rep in ("lrslam", "eslam"):
        start, cell, _ = scene_at_start(rep)
        entry: dict = {"shapes": {}, "cell_m": cell}
        for shape, axes in SHAPES.items():
            scene = copy.deepcopy(start)
            ser = grow_series(scene, cell, axes, args.steps)
            entry["shapes"][shape] = {"series": ser, "fit": fit(ser)}
            f = entry["shapes"][shape]["fit"]
            print(f"{rep:7s} {shape:9s} {ser[0]['parameters']:>11,} -> {ser[-1]['parameters']:>11,} parameters; "
                  f"b {f['b_per_m']:,.0f}/m, c {f['c_per_m2']:,.0f}/m^2 ({100 * f['quadratic_share_at_end']:.1f} % "
                  f"of the growth at the end), log-log slope {f['loglog_slope_last_half']:.2f}", flush=True)
            del scene
        # one cell on each single side: what a run's growth of that side adds
        side = {}
        for ax in "xyz":
            ser = grow_series(copy.deepcopy(start), cell, (ax,), 1)
            side[f"{ax}+"] = ser[1]["parameters"] - ser[0]["parameters"]
        entry["one_cell_per_side"] = side
        if walk is not None:
            got = walk_increments(walk, rep)
            # a growth of several cells or sides adds the sum of its cells' increments (to first order)
            entry["walk_increments"] = got
            entry["walk_increments_match_one_side"] = all(g in side.values() for g in got)
            print(f"{rep:7s} one cell per side {side}; the walk's {len(got)} growths added {sorted(set(got))}: "
                  f"{'each equal to one side' if entry['walk_increments_match_one_side'] else 'not all one side'}")
        res["representations"][rep] = entry
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "walk_slopes.json").write_text(json.dumps(res, indent=1) + "\n")
    print(f"written {args.out / 'walk_slopes.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
