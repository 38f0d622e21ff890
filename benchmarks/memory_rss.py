"""Resident memory over a long run: RSS every 50 frames of a 1000-frame synthetic sequence, against the keyframe
store's bytes, for the default keyframe storage and the options that bound it.

After the first 100 frames a run's memory should grow only with what it keeps, mostly its keyframe store (one keyframe per
``keyframe_every`` mapped frames, ``slam.engine.keyframes.bytes_per_keyframe`` each). The script records, per setting,
RSS (``/proc/self/status`` VmRSS), the keyframe count and the store's bytes, fits RSS growth after frame 100
against the store's growth, and reports the ATE of each setting (the bound's cost in accuracy).

Usage::

    python benchmarks/memory_rss.py --out benchmarks/results/memory_rss --docs     # ~3 runs of 1000 frames
    python benchmarks/memory_rss.py --frames 200 --settings default                   # quick look

Writes ``memory_rss.json`` (per-setting series and summary), ``memory_rss.csv`` and ``memory_rss.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SETTINGS = {
    "default": [],
    "compact": ["mapping.keyframe_storage=compact"],
    "max_keyframes=60": ["mapping.max_keyframes=60"],
}


def rss_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def run_setting(name: str, data: Path, frames: int, every: int) -> dict:
    import numpy as np

    from slam.config import load_config
    from slam.engine.keyframes import bytes_per_keyframe
    from slam.engine.observers import Observer
    from slam.run.outputs import trajectory_metrics
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={data}", f"data.max_frames={frames}", *SETTINGS[name]])
    series = []

    class Probe(Observer):
        def on_frame(self, run, rec):
            if rec.k % every == 0 or rec.k == frames - 1:
                series.append({"frame": rec.k, "rss_mb": rss_bytes() / 2**20, "keyframes": len(s.keyframes),
                               "store_mb": s.keyframes.nbytes / 2**20})

    t0 = time.perf_counter()
    s = SLAM(cfg, load_data(cfg))
    s.run(progress=True, observers=[Probe()])
    wall = time.perf_counter() - t0
    m = trajectory_metrics(s)
    s.close()
    after = [p for p in series if p["frame"] >= 100]
    d_rss = after[-1]["rss_mb"] - after[0]["rss_mb"]
    d_store = after[-1]["store_mb"] - after[0]["store_mb"]
    # the growth of RSS explained by the store: slope of RSS against the store's bytes after frame 100
    x = np.array([p["store_mb"] for p in after])
    y = np.array([p["rss_mb"] for p in after])
    slope = float(np.polyfit(x, y, 1)[0]) if np.ptp(x) > 0 else None
    return {"setting": name, "overrides": SETTINGS[name], "series": series, "wall_s": wall,
            "ate_rmse_cm": None if m["ate_rmse_m"] is None else 100 * m["ate_rmse_m"],
            "fpt_s": m["fpt_s"], "keyframes": len(s.keyframes), "dropped": s.keyframes.dropped,
            "bytes_per_keyframe": bytes_per_keyframe(s.intr.height, s.intr.width, cfg.mapping.keyframe_storage),
            "rss_growth_after_100_mb": d_rss, "store_growth_after_100_mb": d_store,
            "rss_over_store": (d_rss / d_store) if d_store > 0 else None, "rss_vs_store_slope": slope}


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        f = [p["frame"] for p in r["series"]]
        ax.plot(f, [p["rss_mb"] for p in r["series"]], label=f"{r['setting']}: RSS")
        ax.plot(f, [p["store_mb"] + r["series"][0]["rss_mb"] - r["series"][0]["store_mb"] for p in r["series"]],
                "--", label=f"{r['setting']}: first RSS + keyframe store", alpha=0.7)
    ax.set_xlabel("frame")
    ax.set_ylabel("MiB")
    ax.set_title("Resident memory over a 1000-frame synthetic run")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--every", type=int, default=50, help="frames between RSS samples")
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "memory_rss"))
    ap.add_argument("--docs", action="store_true", help="write the table into docs/benchmarks.md")
    args = ap.parse_args(argv)
    if args.frames < 150:
        ap.error("--frames must be >= 150 (growth is measured after frame 100)")

    from _stamp import stamp, write_block

    from slam.data.synthetic import SynthConfig, default_sequence

    data = default_sequence(cfg=SynthConfig(frames=args.frames))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # one process per setting would measure each from a clean heap; in one process the earlier runs' freed
    # memory stays with glibc (keep_freed_memory), so each setting runs in its own child process
    import subprocess

    results = []
    for name in args.settings:
        child = out / f"{name}.json"
        code = (f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); sys.path.insert(0, {str(Path(__file__).parent)!r}); "
                f"import memory_rss as m; r = m.run_setting({name!r}, __import__('pathlib').Path({str(data)!r}), "
                f"{args.frames}, {args.every}); open({str(child)!r}, 'w').write(json.dumps(r))")
        subprocess.run([sys.executable, "-c", code], check=True)
        results.append(json.loads(child.read_text()))
        child.unlink()
    st = stamp()
    (out / "memory_rss.json").write_text(json.dumps({"stamp": st, "frames": args.frames, "results": results}, indent=2))
    with open(out / "memory_rss.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["setting", "frame", "rss_mb", "keyframes", "store_mb"])
        for r in results:
            for p in r["series"]:
                w.writerow([r["setting"], p["frame"], f"{p['rss_mb']:.1f}", p["keyframes"], f"{p['store_mb']:.1f}"])
    plot(results, out / "memory_rss.png")
    lines = [f"Measured {st['date']} with tdfields {st['tdfields_version']}, torch {st['torch_version']}, on {st['cpu']}; "
             f"{args.frames}-frame synthetic sequence, `python benchmarks/memory_rss.py`.", "",
             "| setting | keyframes (dropped) | bytes / keyframe | RSS growth after frame 100 | keyframe store growth | "
             "RSS / store growth | ATE RMSE | FPT |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results:
        ratio = "-" if r["rss_over_store"] is None else f"{r['rss_over_store']:.2f}"
        lines.append(f"| {r['setting']} | {r['keyframes']} ({r['dropped']}) | {r['bytes_per_keyframe']:,} | "
                     f"{r['rss_growth_after_100_mb']:.1f} MiB | {r['store_growth_after_100_mb']:.1f} MiB | {ratio} | "
                     f"{r['ate_rmse_cm']:.2f} cm | {r['fpt_s']:.3f} s |")
    table = "\n".join(lines)
    print(table)
    if args.docs:
        import shutil

        shutil.copy(out / "memory_rss.png", ROOT / "docs" / "images" / "memory_rss.png")
        write_block(ROOT / "docs" / "benchmarks.md", "memory-rss", table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
