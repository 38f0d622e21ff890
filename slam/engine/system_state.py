"""A SLAM loop's state for checkpoints (:mod:`slam.run.checkpoint`): :func:`system_state` composes it from the
loop's parts, :func:`load_system_state` puts a freshly built loop (same config and data) back into it."""

from __future__ import annotations

import torch

from slam.engine.realtime import pass_over
from slam.engine.rng import rng_state, set_rng_state
from slam.engine.setup import data_fingerprint, fingerprint_mismatch
from slam.engine.state import RunState
from slam.errors import SlamInputError
from slam.model.box_resize import load_scene_state
from slam.model.scene import scene_size

__all__ = ["load_system_state", "system_state"]


def system_state(s) -> dict:
    """The state of ``s`` (a :class:`slam.engine.system.SLAM`), after waiting for a mapping call in progress
    (pending calls stay pending): the run state, the keyframes, the mapper's queue, the guard, the random streams,
    the boxes as grown and the data's fingerprint. Plain tensors and numbers (``torch.load(weights_only=True)``
    reads it)."""
    s.mapper.wait_idle()
    return {"state": s.state.state_dict(), **s.keyframes.state_dict(), **s.mapper.state_dict(),
            "guard": s.guard.state_dict(), "rng": rng_state(s.gen, s.map_gen),
            "growth": {**s.growth.state_dict(), "bound": s.bound, "mc_bound": s.mc_bound, "aabb": s.aabb.clone()},
            "fingerprint": data_fingerprint(s.ds, s.selection),
            **({"loops": s.loops.state_dict()} if s.loops is not None else {})}


def load_system_state(s, run: dict, scene: dict) -> None:
    """Put ``s`` (freshly built, same config and data) into a :func:`system_state`'s state ``run``, with the
    mapper's map ``scene`` (a scene ``state_dict``).

    Raises:
        SlamInputError: the data differ from the checkpointed run's, the map does not fit this config, or a
            keyframe can no longer be read."""
    why = fingerprint_mismatch(run["fingerprint"], s.ds, s.selection)
    if why:
        raise SlamInputError(f"the data differ from the checkpointed run's ({why}): resume with the same data "
                             "folder and config")
    try:
        load_scene_state(s.scene, scene)
        s.mapper.load_state_dict(run)
        if s.mapper.applied:  # the first map was taken before the stop: no warm-up odometry (track_by_odometry)
            s.odometry_first = False
    except RuntimeError as exc:  # missing keys or other shapes: not this config's scene
        first = str(exc).strip().splitlines()[0]
        raise SlamInputError(f"the checkpoint's scene does not fit this run's config ({first})") from None
    s.state = RunState.from_state_dict(run["state"])
    dropped, s.state.dropped = set(s.state.dropped), []  # a real-time run's: the same frames passed over
    pass_over(s, [k for k, i in enumerate(s.indices) if i in dropped])
    if "last_keyframe" not in run["state"]:  # a checkpoint from before it was kept: the newest keyframe submitted
        made = [kf["k"] for kf in run["keyframes"]] + [p["k"] for p in run["pending"] if p["keyframe"]]
        s.state.last_keyframe = max(made, default=-1)
    s.keyframes.load_state_dict(run, lambda k: _readable_images(s, k))
    if s.state.prev_depth_k >= 0:
        s.state.prev_depth = s.frames.get(s.state.prev_depth_k).depth
    s.guard.load_state_dict(run["guard"])
    grown = run.get("growth", {})  # absent in a checkpoint from before the box could grow
    s.growth.load_state_dict(grown)
    if "aabb" in grown:
        s.bound, s.mc_bound, s.aabb = grown["bound"], grown["mc_bound"], grown["aabb"].clone()
    s.size = scene_size(s.scene)
    set_rng_state(run["rng"], s.gen, s.map_gen)
    if s.loops is not None and "loops" in run:
        s.loops.load_state_dict(run["loops"])
    elif s.loops is not None and s.state.est:
        raise SlamInputError("the checkpoint was written without loop closure: resume it with loops.enabled=false")


def _readable_images(s, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    frame = s.frames.get(k)
    if not frame.ok:
        raise SlamInputError(f"keyframe {k} can no longer be read: {frame.error}")
    return frame.color.cpu(), frame.depth.cpu()
