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
from slam.engine.runtime import cpu_name, float_fingerprint
from slam.model.scene import parameter_counts

log = logging.getLogger("slam")


def write_trajectories(run, out: Path) -> None:
    """``trajectory.txt`` (and ``trajectory_gt.txt`` with ground truth) in TUM format, for the frames done
    (``run``: a :class:`slam.engine.view.RunView`); after loop closure ``trajectory.txt`` is the corrected trajectory
    and ``trajectory_odometry.txt`` the tracker's."""
    from slam import eval as seval

    ts = run.frame_timestamps()
    poses = run.poses()
    with replacing(out / "trajectory.txt", "trajectory") as tmp:
        seval.write_tum_trajectory(tmp, ts, poses)
    if run.state.corrected is not None:  # loop closure ran: the tracker's own trajectory beside the corrected one
        with replacing(out / "trajectory_odometry.txt", "odometry trajectory") as tmp:
            seval.write_tum_trajectory(tmp, ts, run.odometry_poses())
    if run.gt is not None:
        with replacing(out / "trajectory_gt.txt", "ground-truth trajectory") as tmp:
            seval.write_tum_trajectory(tmp, ts, run.gt[: len(poses)].numpy())


def trajectory_metrics(run, out: Path | None = None, plot: bool = True) -> dict:
    """Run summary (frames, FPT, parameters, machine, events) and ATE against ground truth when there is one;
    with ``out`` and ``plot`` also ``trajectory.png``."""
    import tdfields
    from slam import eval as seval
    from slam.errors import SlamInputError

    cfg = run.cfg
    times = run.state.frame_times
    metrics: dict = {
        "name": cfg.name,
        "representation": cfg.representation,
        "seed": cfg.seed,
        "num_frames": len(run.state.est),
        "fpt_s": float(np.mean(times)) if times else None,
        "parameters": parameter_counts(run.scene),
        "device": str(run.device),
        "cpu": cpu_name(),
        "float_fingerprint": float_fingerprint(),
        "threads": cfg.threads,
        "version": tdfields.__version__,
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "events": run.state.events,
        "tracking_iters_mean": (float(np.mean([t["iters"] for t in run.state.tracking]))
                                if run.state.tracking else None),
        "frames_lost": sum(1 for e in run.state.events if e.get("lost")),
        "frames_recovered": sum(1 for e in run.state.events if e.get("recovered")),
        # a real-time run's frames before the map reached the camera (slam.engine.tracking.track_by_odometry)
        "frames_odometry": sum(1 for e in run.state.events if e.get("odometry")),
    }
    if run.state.loop_summary is not None:
        metrics["loops"] = run.state.loop_summary
    if run.state.refined is not None:
        metrics["map_refined"] = run.state.refined
    # the turn and move between the frames the run took (a real-time run's: the ones it did not drop)
    metrics["frame_steps"] = seval.frame_steps(run.poses()) if run.state.est else None
    if cfg.data.realtime:
        from slam.engine.realtime import latency_summary

        metrics["realtime"] = latency_summary(run.state.latency, len(run.state.dropped))
    metrics.update(ate_rmse_m=None, ate_mean_m=None)
    if run.gt is not None and len(run.state.est) >= 3:
        poses = run.poses()
        gt = run.gt[: len(poses)].numpy()
        try:
            res = seval.ate(poses, gt)
        except SlamInputError as exc:  # e.g. too few frames with valid ground truth
            log.warning("ATE not computed: %s", exc)
        else:
            metrics.update(ate_rmse_m=res.rmse, ate_mean_m=res.mean, ate_median_m=res.median, ate_max_m=res.max)
            if run.state.corrected is not None:
                metrics["ate_odometry_rmse_m"] = seval.ate(run.odometry_poses(), gt).rmse
            if run.state.loop_summary is not None:
                loop_truth(run.state.loop_summary, gt)
            if out is not None and plot:
                try:
                    seval.plot_trajectory(poses, gt, out / "trajectory.png")
                except Exception as exc:  # plotting must not lose a run
                    log.warning("trajectory plot failed: %s", exc)
    return metrics


def loop_truth(summary: dict, gt: np.ndarray) -> None:
    """Each accepted loop's error against the ground truth ``gt [N, 4, 4]`` (its relative pose against the true
    one: ``gt_error_m``, ``gt_error_deg``) and the largest in ``summary``, where both frames have ground truth:
    how a run with ground truth shows that no loop was false."""
    from slam.core.pose import pose_gap

    errors = []
    for lp in summary["accepted"]:
        a, b = gt[lp["match"]], gt[lp["query"]]
        if np.isfinite(a).all() and np.isfinite(b).all():
            dt, dr = pose_gap(np.linalg.inv(a) @ b, np.asarray(lp["relative_pose"]))
            lp.update(gt_error_m=round(dt, 4), gt_error_deg=round(dr, 3))
            errors.append((dt, dr))
    if errors:
        summary.update(gt_error_max_m=round(max(e[0] for e in errors), 4),
                       gt_error_max_deg=round(max(e[1] for e in errors), 3))


def write_frames(run, out: Path) -> None:
    """``frames.csv``: one row per processed frame (position, dataset frame, wall seconds, trusted, what it was
    tracked on (``depth``; ``color`` for a frame without depth whose colour pose was taken, ``prediction`` where colour
    tracking ran and was not taken; ``odometry`` for a real-time run's frame before the first map, tracked by depth
    ICP, ``prediction`` where that was not taken; empty where nothing was tracked), the tracking's best loss (the depth tracking
    loss, or the colour error for colour tracking), the iterations run and the inlier share (colour: the share of the
    pixels that see the map), and the scene's parameters and field bytes after the frame: they change where the box
    grew, :mod:`slam.engine.growth_policy`), and ``loop_with``: the dataset frame a loop closed this frame with."""
    import csv
    import io

    st = run.state
    tracked = {t["frame"]: dict(t, on="depth") for t in st.tracking}
    for e in st.events:
        if "odometry" in e:  # a real-time run's frame before the first map (slam.engine.tracking.track_by_odometry)
            tracked[e["frame"]] = {"on": "odometry" if e["odometry"] else "prediction"}
        if "color_loss" in e:
            tracked[e["frame"]] = {"on": "color" if e["color_tracked"] else "prediction", "loss": e["color_loss"],
                                   "iters": e["color_iters"], "inliers": e["color_share"]}
    buf = io.StringIO()
    w = csv.writer(buf)
    loops = {e["frame"]: e["with_frame"] for e in st.events if e.get("event") == "loop closed"}
    w.writerow(["k", "frame", "seconds", "trusted", "tracked_on", "tracking_loss", "tracking_iters",
                "tracking_inliers", "parameters", "field_bytes", "loop_with"])
    for k in range(len(st.est)):
        i = int(run.indices[k])
        t = tracked.get(i, {})
        sec = st.frame_times[k] if k < len(st.frame_times) else ""
        size = (st.sizes[k] if k < len(st.sizes) else None) or ("", "")  # None: resumed from an older checkpoint
        w.writerow([k, i, f"{sec:.4f}" if sec != "" else "", int(st.trusted[k]), t.get("on", ""), t.get("loss", ""),
                    t.get("iters", ""), t.get("inliers", ""), *size, loops.get(i, "")])
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


def write_mesh(run, out: Path, metrics: dict):
    """Extract, cull and write ``mesh.ply``; adds ``mesh_s``, ``mesh_faces`` and (with a GT mesh)
    ``reconstruction`` to ``metrics``. Returns the mesh."""
    from slam.model.mesher import run_mesh

    t0 = time.perf_counter()
    m = run_mesh(run)
    metrics["mesh_s"] = time.perf_counter() - t0
    metrics["mesh_faces"] = int(len(m.faces))
    with replacing(out / "mesh.ply", "mesh") as tmp:
        m.export(tmp)
    if run.gt_mesh_path is not None and len(m.faces):
        metrics["reconstruction"] = reconstruction(m, run.gt_mesh_path, run)
    return m


def reconstruction(mesh, gt_mesh_path, run) -> dict:
    """Accuracy / completion / completion ratio (5 cm) and Depth L1 against the GT mesh (slam.eval).

    Reference protocol: the GT mesh is culled with the GT poses (same rule and truncation as the
    reconstruction), the reconstruction is ICP-aligned to it (``evaluation.icp``), then both are sampled
    (``evaluation.samples`` points each); Depth L1 over ``evaluation.depth_l1_views`` random views.
    """
    from slam import eval as seval

    cfg = run.cfg
    gt = seval.load_mesh(gt_mesh_path, "ground-truth mesh")
    if run.gt is not None:
        depths = None
        if cfg.meshing.cull_depth_test:
            depths = (run.read_depth(k) for k in range(len(run.indices)))
        gt = seval.cull_mesh(gt, run.gt.numpy(), run.intrinsics, depths=depths, truncation=cfg.scene.truncation)
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
