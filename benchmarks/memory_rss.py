"""Resident memory over a long run, broken down: RSS every ``--every`` frames, next to what the run holds (the
scene and the tracker's copy, keyframe images in memory and on disk, the per-frame records), for settings and
presets side by side, each in its own process.

Two sequences:

* ``room``: the bundled synthetic room's camera loop at 120x160 with ``--frames`` frames (preset ``synthetic``).
* ``tum-loop``: the two TUM fr1_rpy excerpts (pairs 0-224) walked back and forth to ``--frames`` frames: a long
  real sequence (the folder is symbolic links plus new timestamps; ground truth interpolated at each colour
  image). Presets ``tum/fr1_rpy-cpu`` (lrslam) and ``tum/fr1_rpy-eslam-cpu`` (eslam).

Settings (any with any sequence): ``after`` (the defaults: the newest ``mapping.keyframes_in_memory`` keyframes'
images in memory, older ones on disk; the heap's free pages returned every ``trim_memory_every`` frames),
``before`` (``mapping.keyframes_in_memory=0 trim_memory_every=0``: every keyframe in memory and no trim, as before
either existed), ``no_trim`` (the spill without the trim), ``heap_returned`` (no trim, glibc's own trimming and
mmap of big blocks: ``keep_freed_memory=false``), ``compact`` and ``max_keyframes=60`` (the older bounds). Each run
records:

* ``rss_mb`` and ``peak_rss_mb`` (``/proc/self/status`` VmRSS, VmHWM);
* the breakdown: ``base_mb`` (RSS after importing everything, before the run: interpreter, torch, numba),
  ``scene_mb`` (parameters and buffers of the map and of the tracker's copy), ``keyframes_mb`` (images in memory),
  ``spilled_mb`` (on disk, not in RSS), ``records_mb`` (the run state: poses, times, events, per-frame records,
  counted object by object), ``working_mb`` = the rest (the heap the allocator keeps for a mapping or tracking
  call's temporaries, Adam's state and the frozen-field caches of a call, compiled kernels);
* ``rss_growth_after_<N>_mb_per_100``: the least-squares slope of RSS per 100 frames after frame ``--after``.

Usage::

    python benchmarks/memory_rss.py --sequence room --frames 5000 --every 250 --settings after \\
        --out benchmarks/results/memory_rss_5000
    LRSLAM_SHARED_DATA=../shared/data python benchmarks/memory_rss.py --sequence tum-loop --frames 400 \\
        --settings before after --presets tum/fr1_rpy-cpu tum/fr1_rpy-eslam-cpu --out benchmarks/results/memory_rss_tum

Writes ``memory_rss.json`` (per run: series, breakdown, summary; rewritten after every sample, so a stopped run
keeps what it measured), ``memory_rss.csv`` and ``memory_rss.png``.

Meshing (``--mesh RUN``): ``lrslam mesh RUN --resolution R --set meshing.block_cells=N`` for each ``--block-cells``
value (0: the dense volume), each in a fresh process: its peak RSS (``ru_maxrss``), wall time, vertices and faces;
then each mesh's accuracy, completion and completion ratio against the dataset's ground-truth mesh with the run's
own protocol (:func:`slam.run.outputs.reconstruction`: the GT culled with the GT poses, ICP, the same samples).
Writes ``mesh_rss.json``::

    python benchmarks/memory_rss.py --mesh runs/walk --resolution 0.02 --block-cells 0 32 \
        --out benchmarks/results/walk_mesh
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SETTINGS = {
    "after": [],
    "before": ["mapping.keyframes_in_memory=0", "trim_memory_every=0"],
    "compact": ["mapping.keyframe_storage=compact"],
    "max_keyframes=60": ["mapping.max_keyframes=60"],
    "no_trim": ["trim_memory_every=0"],
    "heap_returned": ["keep_freed_memory=false", "trim_memory_every=0"],
}
TUM_PARTS = ("tum_fr1_rpy_0_124", "tum_fr1_rpy")


def status_mb(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {key} in /proc/self/status")


def deep_bytes(obj, seen=None) -> int:
    """Bytes held by ``obj`` and what it refers to through lists, tuples, dicts and dataclasses (tensors: object
    plus storage)."""
    import dataclasses

    import torch

    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    n = sys.getsizeof(obj)
    if isinstance(obj, torch.Tensor):
        return n + obj.untyped_storage().nbytes()
    if isinstance(obj, dict):
        return n + sum(deep_bytes(k, seen) + deep_bytes(v, seen) for k, v in obj.items())
    if isinstance(obj, (list, tuple, set)):
        return n + sum(deep_bytes(v, seen) for v in obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return n + sum(deep_bytes(getattr(obj, f.name), seen) for f in dataclasses.fields(obj))
    return n


def tensor_bytes(tensors) -> int:
    storages = {}
    for t in tensors:
        storages[t.untyped_storage().data_ptr()] = t.untyped_storage().nbytes()
    return sum(storages.values())


def breakdown(s, base_mb: float) -> dict:
    """What the run ``s`` (a :class:`slam.engine.system.SLAM`) holds now, in MiB (see the module docstring)."""
    scenes = {id(s.scene): s.scene, id(s.mapper.track_scene): s.mapper.track_scene}
    scene = tensor_bytes(t for m in scenes.values() for t in (*m.parameters(), *m.buffers())) / 2**20
    kf = s.keyframes.nbytes / 2**20
    rec = deep_bytes(s.state) / 2**20
    rss = status_mb("VmRSS")
    return {"rss_mb": rss, "peak_rss_mb": status_mb("VmHWM"), "base_mb": base_mb, "scene_mb": scene,
            "keyframes_mb": kf, "spilled_mb": s.keyframes.spilled_bytes / 2**20, "records_mb": rec,
            "working_mb": rss - base_mb - scene - kf - rec, "keyframes": len(s.keyframes)}


def looped_tum(shared: Path, frames: int, out: Path) -> Path:
    """A TUM folder of ``frames`` frames walking fr1_rpy's pairs 0-224 forth and back (symbolic links, 30 Hz
    timestamps, ground truth at each colour image). The folder name keeps ``fr1`` (the camera is chosen by it)."""
    import numpy as np
    from scipy.spatial.transform import Rotation, Slerp

    from slam.data.tum_format import read_associations, read_tum_poses

    pairs = []  # (rgb path, depth path, [7] pose)
    for part in TUM_PARTS:
        src = shared / part
        ts, rgb, depth = read_associations(src / "associations.txt")
        gt = read_tum_poses(src / "groundtruth.txt")
        gt = gt[np.argsort(gt[:, 0])]
        rot = Slerp(gt[:, 0], Rotation.from_quat(gt[:, 4:8]))(ts).as_quat()
        pos = np.stack([np.interp(ts, gt[:, 0], gt[:, i]) for i in (1, 2, 3)], -1)
        pairs += [(src / r, src / d, np.concatenate([pos[i], rot[i]])) for i, (r, d) in enumerate(zip(rgb, depth))]
    cycle = list(range(len(pairs))) + list(range(len(pairs) - 2, 0, -1))
    root = out / "data" / f"tum_fr1_rpy_loop_{frames}"
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(exist_ok=True)
    assoc, gt_rows = [], []
    for j in range(frames):
        rgb, depth, pose = pairs[cycle[j % len(cycle)]]
        t = 1305031233.0 + j / 30.0
        for kind, path in (("rgb", rgb), ("depth", depth)):
            link = root / kind / f"{j:06d}.png"
            if not link.is_symlink():
                link.symlink_to(path.resolve())
        assoc.append(f"{t:.6f} rgb/{j:06d}.png {t:.6f} depth/{j:06d}.png")
        gt_rows.append(f"{t:.6f} " + " ".join(f"{v:.7f}" for v in pose))
    (root / "associations.txt").write_text("\n".join(assoc) + "\n")
    (root / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(gt_rows) + "\n")
    return root


def run_one(preset: str, setting: str, data: str, frames: int, every: int, after: int, out_json: str) -> None:
    """One run in this process; rewrites ``out_json`` after every sample. (Its frame time is kept in the JSON
    but not tabled: memory, not time, is what this measures, and the runs need not have the machine alone.)"""
    from slam.config import load_config
    from slam.engine.observers import Observer
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.run.outputs import trajectory_metrics

    cfg = load_config(preset, [f"data.path={data}", f"data.max_frames={frames}", *SETTINGS[setting]])
    base_mb = status_mb("VmRSS")
    series = []
    result = {"preset": preset, "setting": setting, "overrides": SETTINGS[setting], "frames": frames, "series": series}

    def save():
        Path(out_json).write_text(json.dumps(result))

    class Probe(Observer):
        def on_frame(self, run, rec):
            if rec.k % every == 0 or rec.k == frames - 1:
                series.append({"frame": rec.k, **breakdown(s, base_mb)})
                save()

    t0 = time.perf_counter()
    s = SLAM(cfg, load_data(cfg))
    s.run(progress=True, observers=[Probe()])
    s.close()
    m = trajectory_metrics(s.view())
    late = [p for p in series if p["frame"] >= after]
    import numpy as np

    slope = (100 * float(np.polyfit([p["frame"] for p in late], [p["rss_mb"] for p in late], 1)[0])
             if len(late) >= 2 else None)
    result.update({"wall_s": time.perf_counter() - t0, "fpt_s": m["fpt_s"],
                   "ate_rmse_cm": None if m["ate_rmse_m"] is None else 100 * m["ate_rmse_m"],
                   "peak_rss_mb": status_mb("VmHWM"), "after_frame": after,
                   f"rss_growth_after_{after}_mb_per_100": slope, "final": breakdown(s, base_mb)})
    save()


def plot(results: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for r in results:
        f = [p["frame"] for p in r["series"]]
        line, = ax.plot(f, [p["rss_mb"] for p in r["series"]], label=f"{r['preset']} {r['setting']}: RSS")
        ax.plot(f, [p["base_mb"] + p["scene_mb"] + p["keyframes_mb"] + p["records_mb"] for p in r["series"]], "--",
                color=line.get_color(), alpha=0.6, label=f"{r['preset']} {r['setting']}: base + scene + keyframes "
                "+ records")
    ax.set_xlabel("frame")
    ax.set_ylabel("MiB")
    ax.set_title(title)
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def table(results: list[dict], st: dict, title: str) -> str:
    from _stamp import stamp_line

    lines = [f"{stamp_line(st)} {title}.", "",
             "| preset | setting | keyframes | peak RSS | final RSS | base | scene | keyframes in RAM | on disk | "
             "records | working | RSS growth / 100 frames after frame N | ATE RMSE |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        f = r.get("final") or r["series"][-1]
        n = r.get("after_frame")
        slope = r.get(f"rss_growth_after_{n}_mb_per_100")
        ate = "-" if r.get("ate_rmse_cm") is None else f"{r['ate_rmse_cm']:.2f} cm"
        lines.append(
            f"| {r['preset']} | {r['setting']} | {f['keyframes']} | {r.get('peak_rss_mb', f['peak_rss_mb']):.0f} MiB | "
            f"{f['rss_mb']:.0f} MiB | {f['base_mb']:.0f} | {f['scene_mb']:.1f} | {f['keyframes_mb']:.0f} | "
            f"{f['spilled_mb']:.0f} | {f['records_mb']:.1f} | {f['working_mb']:.0f} | "
            f"{'-' if slope is None else f'{slope:.1f} MiB (N = {n})'} | {ate} |")
    return "\n".join(lines)


def mesh_one(run: str, resolution: float, cells: int, ply: str, out_json: str) -> None:
    """``lrslam mesh`` of ``run`` in this process (a fresh one: ``ru_maxrss`` is the process's peak)."""
    import resource

    import torch

    from slam.cli import main as cli

    t0 = time.perf_counter()
    code = cli(["mesh", run, "--resolution", str(resolution), "--out", ply, "--set", f"meshing.block_cells={cells}"])
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    import trimesh  # only now: its modules would count in the peak (the block path never imports it)

    m = trimesh.load(ply, process=False)
    Path(out_json).write_text(json.dumps({"block_cells": cells, "exit": code, "wall_s": wall, "peak_rss_mb": peak,
                                          "torch_threads": torch.get_num_threads(), "vertices": len(m.vertices),
                                          "faces": len(m.faces)}))


def mesh_quality(run: str, ply: str) -> dict:
    """Accuracy / completion of the mesh ``ply`` against the GT mesh of ``run``'s dataset, as a run scores its own
    (:func:`slam.run.outputs.reconstruction`, with the run's frames, GT poses and depth)."""
    from types import SimpleNamespace

    import numpy as np
    import torch
    import trimesh

    from slam.commands.mesh import load_run_checkpoint
    from slam.data.types import Intrinsics
    from slam.engine.frames import readable_depth
    from slam.engine.setup import load_data
    from slam.run.outputs import reconstruction

    cfg, _, extra = load_run_checkpoint(Path(run) / "checkpoint.pt")
    ds = load_data(cfg)
    idx = list(extra["frame_indices"])
    view = SimpleNamespace(cfg=cfg, indices=idx, intrinsics=Intrinsics(**extra["intrinsics"]),
                           gt=torch.as_tensor(np.asarray(ds.gt_poses), dtype=torch.float32)[idx],
                           read_depth=lambda k: readable_depth(ds, idx[k]))
    return reconstruction(trimesh.load(ply, process=False), ds.gt_mesh_path, view)


def mesh_table(d: dict) -> str:
    from _stamp import stamp_line

    lines = [f"{stamp_line(d['stamp'])} `lrslam mesh` of {d['run']} at {100 * d['resolution']:g} cm, each in a fresh "
             "process.", "",
             "| extraction | peak RSS | wall time | vertices | faces | accuracy | completion | completion ratio (5 cm) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in d["results"]:
        q = r["reconstruction"]
        name = "dense" if r["block_cells"] == 0 else f"blocks of {r['block_cells']} cells"
        lines.append(f"| {name} | {r['peak_rss_mb']:.0f} MiB | {r['wall_s']:.0f} s | {r['vertices']:,} | "
                     f"{r['faces']:,} | {100 * q['accuracy_m']:.2f} cm | {100 * q['completion_m']:.2f} cm | "
                     f"{100 * q['completion_ratio']:.1f} % |")
    return "\n".join(lines)


def mesh_main(args, out: Path) -> int:
    """The ``--mesh`` mode (see the module docstring)."""
    import tempfile

    from _stamp import stamp

    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for cells in args.block_cells:
            ply, child = f"{tmp}/mesh_{cells}.ply", f"{tmp}/mesh_{cells}.json"
            code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import memory_rss as m; "
                    f"m.mesh_one({args.mesh!r}, {args.resolution!r}, {cells}, {ply!r}, {child!r})")
            subprocess.run([sys.executable, "-c", code], check=True)
            results.append(json.loads(Path(child).read_text()))
        for r in results:
            r["reconstruction"] = mesh_quality(args.mesh, f"{tmp}/mesh_{r['block_cells']}.ply")
    st = stamp()
    st["torch_threads"] = results[0]["torch_threads"]  # lrslam mesh computes with the run's threads, not this one's
    d = {"stamp": st, "run": args.mesh_name or Path(args.mesh).name, "resolution": args.resolution,
         "results": results}
    metrics = Path(args.mesh) / "metrics.json"
    if metrics.is_file():  # how far the run's own trajectory was off: the distances above include it
        d["run_ate_rmse_m"] = json.loads(metrics.read_text()).get("ate_rmse_m")
    (out / "mesh_rss.json").write_text(json.dumps(d, indent=2))
    print(mesh_table(d))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequence", choices=("room", "tum-loop"), default="room")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--every", type=int, default=50, help="frames between samples")
    ap.add_argument("--after", type=int, default=None, help="fit RSS growth after this frame (default: frames / 10, "
                    "at least 100)")
    ap.add_argument("--settings", nargs="+", default=["before", "after"], choices=list(SETTINGS))
    ap.add_argument("--presets", nargs="+", default=None, help="default: synthetic (room), tum/fr1_rpy-cpu (tum-loop)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "memory_rss"))
    ap.add_argument("--mesh", metavar="RUN", default=None, help="meshing mode: the run folder to mesh")
    ap.add_argument("--mesh-name", default=None, help="the run as the table names it (default: the folder's name)")
    ap.add_argument("--resolution", type=float, default=0.02, help="meshing mode: grid spacing in metres")
    ap.add_argument("--block-cells", type=int, nargs="+", default=[0, 32], help="meshing mode: meshing.block_cells "
                    "values (0: dense)")
    args = ap.parse_args(argv)
    if args.mesh:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        return mesh_main(args, out)
    if args.frames < 150:
        ap.error("--frames must be >= 150 (growth is measured after frame 100)")
    after = args.after if args.after is not None else max(100, args.frames // 10)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.sequence == "room":
        from slam.data.synthetic import SynthConfig, default_sequence

        data = default_sequence(cfg=SynthConfig(frames=args.frames))
        presets = args.presets or ["synthetic"]
        title = f"{args.frames}-frame synthetic room (120x160)"
    else:
        shared = Path(os.environ.get("LRSLAM_SHARED_DATA", ROOT.parent / "shared" / "data"))
        data = looped_tum(shared, args.frames, out)
        presets = args.presets or ["tum/fr1_rpy-cpu"]
        title = f"TUM fr1_rpy pairs 0-224 forth and back to {args.frames} frames"
    from _stamp import stamp

    import torch

    torch.set_num_threads(1)  # the stamp names the runs' thread count (threads: 1 in every preset), not this process's

    results = []
    for preset in presets:
        for setting in args.settings:  # each in a fresh process: a freed heap stays with the process
            child = out / f"{preset.replace('/', '_')}__{setting}.json"
            code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import memory_rss as m; "
                    f"m.run_one({preset!r}, {setting!r}, {str(data)!r}, {args.frames}, {args.every}, {after}, "
                    f"{str(child)!r})")
            subprocess.run([sys.executable, "-c", code], check=True)
            results.append(json.loads(child.read_text()))
            child.unlink()
    st = stamp()
    (out / "memory_rss.json").write_text(json.dumps({"stamp": st, "sequence": args.sequence, "frames": args.frames,
                                                     "results": results}, indent=2))
    with open(out / "memory_rss.csv", "w", newline="") as fh:
        cols = ["frame", "rss_mb", "peak_rss_mb", "base_mb", "scene_mb", "keyframes_mb", "spilled_mb", "records_mb",
                "working_mb", "keyframes"]
        w = csv.writer(fh)
        w.writerow(["preset", "setting", *cols])
        for r in results:
            for p in r["series"]:
                w.writerow([r["preset"], r["setting"], *[round(p[c], 2) for c in cols]])
    plot(results, out / "memory_rss.png", f"Resident memory: {title}")
    text = table(results, st, title)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
