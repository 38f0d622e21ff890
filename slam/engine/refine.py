"""The map follows the corrected poses (docs/loops.md, "Global refinement"): once loop closure has corrected the
trajectory at the end of a run, each mapping keyframe moves with its frame's correction and the fields are re-fitted
on the moved keyframes with their poses fixed (``loops.refine_iters``): Co-SLAM's global bundle adjustment over the
keyframe store, without its pose updates (the pose graph has set them).

Each iteration draws ``mapping.window_size + 1`` keyframes of the whole store (the mapper's window is the newest
frame's neighbours; here every keyframe counts alike) and ``mapping.pixels`` pixels among them, and takes one step of
a fresh Adam over the fields and decoders at the mapping rates: the mapping loss, the mapper's random stream, so a
resumed run refines to the same map. It costs no memory beyond the keyframes the mapper keeps already, and time in
proportion to ``refine_iters``."""

from __future__ import annotations

import logging
import time

import numpy as np
import torch
from tqdm import tqdm

from slam.core.optim import adam
from slam.core.pose import matrix_to_pose, pose_to_matrix
from slam.engine.keyframes import KeyframeStore
from slam.engine.mapper import finite_step, mapping_loss

log = logging.getLogger("slam")


def move_keyframes(keyframes: KeyframeStore, before: np.ndarray, after: np.ndarray) -> float:
    """Each keyframe's pose moved by its frame's correction ``after[k] @ before[k]^-1`` (``before``/``after``:
    ``[N, 4, 4]`` camera-to-world of every frame position, the tracker's and the corrected); returns the largest
    move of a keyframe's position in metres."""
    largest = 0.0
    for kf in keyframes.frames:
        C = torch.from_numpy(np.asarray(after[kf.index], np.float64) @ np.linalg.inv(before[kf.index]))
        old = pose_to_matrix(kf.pose).double()
        new = C @ old
        largest = max(largest, float(torch.linalg.norm(new[:3, 3] - old[:3, 3])))
        kf.pose = matrix_to_pose(new.float()).to(kf.pose.dtype)
    return largest


def refine_fields(scene, keyframes: KeyframeStore, cfg, intrinsics, generator: torch.Generator, iters: int,
                  progress: bool = False) -> dict:
    """``iters`` iterations of the mapping loss over random keyframes of the store, poses fixed (module docstring).

    Args:
        scene: the :class:`slam.model.scene.SceneModel` (optimised in place); keyframes: the store, poses moved.
        generator: the mapper's CPU stream (the keyframes' and the pixels' draws).
        progress: a progress bar (it runs after the last frame's, for seconds).

    Returns:
        ``{"iters", "steps", "skipped", "keyframes", "loss_first", "loss_last", "seconds"}``: steps taken and skipped
        (a non-finite loss or gradient), the mean loss of the first and of the last tenth of the steps.
    """
    t0 = time.perf_counter()
    mc, n = cfg.mapping, len(keyframes)
    device = scene.aabb.device
    opt = adam(scene.param_groups(cfg, 1.0, mc.lr_scaling))
    params = [p for g in opt.param_groups for p in g["params"]]
    take = min(mc.window_size + 1, n)
    losses, skipped = [], 0
    bar = tqdm(range(iters if n else 0), disable=not progress, unit="step", dynamic_ncols=True, leave=False,
               desc=f"refining the map on {n} keyframes")
    for _ in bar:
        pick = torch.randperm(n, generator=generator)[:take].tolist()
        frames = [keyframes.frames[i] for i in pick]
        images = [kf.float_images() for kf in frames]  # one read of each keyframe spilled to disk
        colors = torch.stack([c for c, _ in images]).to(device)
        depths = torch.stack([d for _, d in images]).to(device)
        poses = torch.stack([kf.pose for kf in frames]).to(device)
        loss = mapping_loss(scene, colors, depths, poses, intrinsics, cfg, max(mc.pixels // take, 1), generator)
        if loss is None:
            continue
        opt.zero_grad(set_to_none=True)
        if bool(torch.isfinite(loss)):
            loss.backward()
        if not finite_step(loss, params):
            skipped += 1
            continue
        opt.step()
        losses.append(float(loss.detach()))
    tenth = max(len(losses) // 10, 1)
    return {"iters": iters, "steps": len(losses), "skipped": skipped, "keyframes": n,
            "loss_first": float(np.mean(losses[:tenth])) if losses else float("nan"),
            "loss_last": float(np.mean(losses[-tenth:])) if losses else float("nan"),
            "seconds": time.perf_counter() - t0}


def follow_corrected(s, odometry: np.ndarray, progress: bool = False) -> None:
    """After :func:`slam.loop.closer.close_run_loops` on ``s`` (a :class:`slam.engine.system.SLAM`): when a loop
    corrected the trajectory and ``loops.refine_iters`` > 0, move the keyframes from the tracker's poses
    ``odometry`` ``[N, 4, 4]`` (the ones the graph was given) to the corrected ones, re-fit the map on them, hand
    the tracker's copy the result and record ``state.refined``. Once per run: a resumed run that had refined keeps
    its refined map and moved keyframes."""
    st, iters = s.state, s.cfg.loops.refine_iters
    if st.refined is not None or st.corrected is None or not iters or not st.loop_summary.get("loops"):
        return
    moved = move_keyframes(s.keyframes, odometry, st.corrected)
    stats = refine_fields(s.scene, s.keyframes, s.cfg, s.intr, s.map_gen, iters, progress)
    if s.mapper.track_scene is not s.scene:
        with torch.no_grad():
            s.mapper.track_scene.load_state_dict(s.scene.state_dict())
    st.refined = {**stats, "keyframe_move_max_m": moved}
    st.events.append({"frame": int(s.indices[len(st.est) - 1]), "event": "map refined on the corrected poses",
                      **st.refined})
    log.info("map refined on the corrected poses: %d keyframes moved up to %.3f m, %d iterations in %.1f s",
             stats["keyframes"], moved, stats["steps"], stats["seconds"])
