"""A run's outputs: the TUM trajectories, ``metrics.json``, the trajectory plot, the scene checkpoint, the mesh
and its reconstruction metrics. Every file is written through :mod:`slam.files` (a temporary name, fsync, a
rename): a reader, or a run killed or out of disk while writing, never sees a half-written file, and a write that
fails raises :class:`slam.errors.SlamOutputError` naming the file.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from slam.files import atomic_write_text, replacing
from slam.engine.frames import readable_depth
from slam.engine.runtime import cpu_name
from slam.model.scene import parameter_counts

log = logging.getLogger("slam")


def frame_timestamps(system) -> np.ndarray:
    """``[N]`` seconds of the processed frames (the dataset's timestamps, else 30 Hz from 0)."""
    ts_all = getattr(system.ds, "timestamps", None)
    n = len(system.state.est)
    if ts_all is None:
        return np.arange(n) / 30.0
    return np.asarray([float(ts_all[i]) for i in system.indices[:n]])


def write_trajectories(system, out: Path) -> None:
    """``trajectory.txt`` (and ``trajectory_gt.txt`` with ground truth) in TUM format, for the frames done."""
    from slam import eval as seval

    ts = frame_timestamps(system)
    poses = system.poses_matrix()
    with replacing(out / "trajectory.txt", "trajectory") as tmp:
        seval.write_tum_trajectory(tmp, ts, poses)
    if system.gt is not None:
        with replacing(out / "trajectory_gt.txt", "ground-truth trajectory") as tmp:
            seval.write_tum_trajectory(tmp, ts, system.gt[: len(poses)].numpy())


def trajectory_metrics(system, out: Path | None = None, plot: bool = True) -> dict:
    """Run summary (frames, FPT, parameters, machine, events) and ATE against ground truth when there is one;
    with ``out`` and ``plot`` also ``trajectory.png``."""
    import tdfields
    from slam import eval as seval
    from slam.errors import SlamInputError

    cfg = system.cfg
    times = system.state.frame_times
    metrics: dict = {
        "name": cfg.name,
        "representation": cfg.representation,
        "seed": cfg.seed,
        "num_frames": len(system.state.est),
        "fpt_s": float(np.mean(times)) if times else None,
        "parameters": parameter_counts(system.scene),
        "device": str(system.device),
        "cpu": cpu_name(),
        "threads": cfg.threads,
        "version": tdfields.__version__,
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "events": system.state.events,
        "tracking_iters_mean": (float(np.mean([t["iters"] for t in system.state.tracking]))
                                if system.state.tracking else None),
        "frames_lost": sum(1 for e in system.state.events if e.get("lost")),
        "frames_recovered": sum(1 for e in system.state.events if e.get("recovered")),
    }
    metrics.update(ate_rmse_m=None, ate_mean_m=None)
    if system.gt is not None and len(system.state.est) >= 3:
        poses = system.poses_matrix()
        gt = system.gt[: len(poses)].numpy()
        try:
            res = seval.ate(poses, gt)
        except SlamInputError as exc:  # e.g. too few frames with valid ground truth
            log.warning("ATE not computed: %s", exc)
        else:
            metrics.update(ate_rmse_m=res.rmse, ate_mean_m=res.mean, ate_median_m=res.median, ate_max_m=res.max)
            if out is not None and plot:
                try:
                    seval.plot_trajectory(poses, gt, out / "trajectory.png")
                except Exception as exc:  # plotting must not lose a run
                    log.warning("trajectory plot failed: %s", exc)
    return metrics


def write_frames(system, out: Path) -> None:
    """``frames.csv``: one row per processed frame (position, dataset frame, wall seconds, trusted, and for tracked
    frames the best loss, the iterations run and the inlier share)."""
    import csv
    import io

    st = system.state
    tracked = {t["frame"]: t for t in st.tracking}
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["k", "frame", "seconds", "trusted", "tracking_loss", "tracking_iters", "tracking_inliers"])
    for k in range(len(st.est)):
        i = int(system.indices[k])
        t = tracked.get(i, {})
        sec = st.frame_times[k] if k < len(st.frame_times) else ""
        w.writerow([k, i, f"{sec:.4f}" if sec != "" else "", int(st.trusted[k]), t.get("loss", ""), t.get("iters", ""),
                    t.get("inliers", "")])
    atomic_write_text(out / "frames.csv", buf.getvalue(), "per-frame table")


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


def write_metrics(metrics: dict, out: Path) -> None:
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2, default=str), "metrics")


def write_mesh(system, out: Path, metrics: dict):
    """Extract, cull and write ``mesh.ply``; adds ``mesh_s``, ``mesh_faces`` and (with a GT mesh)
    ``reconstruction`` to ``metrics``. Returns the mesh."""
    t0 = time.perf_counter()
    m = system.mesh()
    metrics["mesh_s"] = time.perf_counter() - t0
    metrics["mesh_faces"] = int(len(m.faces))
    with replacing(out / "mesh.ply", "mesh") as tmp:
        m.export(tmp)
    gt_mesh = getattr(system.ds, "gt_mesh_path", None)
    if gt_mesh is not None and len(m.faces):
        metrics["reconstruction"] = reconstruction(m, gt_mesh, system)
    return m


def reconstruction(mesh, gt_mesh_path, system) -> dict:
    """Accuracy / completion / completion ratio (5 cm) and Depth L1 against the GT mesh (slam.eval).

    Reference protocol: the GT mesh is culled with the GT poses (same rule and truncation as the
    reconstruction), the reconstruction is ICP-aligned to it (``evaluation.icp``), then both are sampled
    (``evaluation.samples`` points each); Depth L1 over ``evaluation.depth_l1_views`` random views.
    """
    from slam import eval as seval

    cfg = system.cfg
    gt = seval.load_mesh(gt_mesh_path, "ground-truth mesh")
    if system.gt is not None:
        depths = None
        if cfg.meshing.cull_depth_test:
            depths = (readable_depth(system.ds, i) for i in system.indices)
        gt = seval.cull_mesh(gt, system.gt.numpy(), system.intr, depths=depths, truncation=cfg.scene.truncation)
    out = {}
    if cfg.evaluation.icp:  # one alignment for both metrics
        mesh, transform = seval.align_mesh(mesh, gt, seed=cfg.seed)
        out["icp_translation_m"] = float(np.linalg.norm(transform[:3, 3]))
    out.update(seval.reconstruction_metrics(mesh, gt, samples=cfg.evaluation.samples, seed=cfg.seed))
    out.pop("samples", None)
    if cfg.evaluation.depth_l1_views == 0:
        out["depth_l1_m"] = None
        return {k: float(v) if isinstance(v, (int, float, np.floating)) else v for k, v in out.items()}
    try:
        out["depth_l1_m"] = float(seval.depth_l1(mesh, gt, views=cfg.evaluation.depth_l1_views, seed=cfg.seed))
    except Exception as exc:  # the metric needs ray casting; never lose a run over it
        log.warning("depth L1 failed: %s", exc)
        out["depth_l1_m"] = None
    return {k: float(v) if isinstance(v, (int, float, np.floating)) else v for k, v in out.items()}
