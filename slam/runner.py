"""A whole SLAM run into a folder: data, the loop, then every output (:mod:`slam.outputs`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

from slam.config import Config, save_config
from slam.observers import Observer
from slam.outputs import save_scene, trajectory_metrics, write_mesh, write_metrics, write_trajectories
from slam.system import SLAM, load_data, resolve_device


def run_to_folder(cfg: Config, out: str | Path, progress: bool = True, mesh: bool = True,
                  observers: Sequence[Observer] = ()) -> dict:
    """Run SLAM and write every output to ``out``; returns the metrics dict (also ``metrics.json``).

    Outputs: ``trajectory.txt`` / ``trajectory_gt.txt`` (TUM format), ``mesh.ply`` (coloured, culled),
    ``trajectory.png``, ``config.yaml``, ``checkpoint.pt`` (tdfields self-describing checkpoint: config, scene
    state_dict, poses) and ``metrics.json``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(cfg.device)
    ds = load_data(cfg)
    save_config(cfg, out / "config.yaml")
    try:
        t_start = time.perf_counter()
        system = SLAM(cfg, ds, device)
        for obs in observers:
            obs.on_start(system)
        system.run(progress=progress, observers=observers)
        t_loop = time.perf_counter() - t_start
        write_trajectories(system, out)
        metrics = trajectory_metrics(system, out)
        metrics["loop_s"] = t_loop
        save_scene(system, out / "checkpoint.pt")
        m = write_mesh(system, out, metrics) if mesh else None
        write_metrics(metrics, out)
        for obs in observers:
            obs.on_finish(system, metrics, m)
    finally:
        for obs in observers:
            obs.close()
    return metrics
