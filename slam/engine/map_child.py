"""The mapping process's side of :mod:`slam.engine.map_process`: what the spawned child runs. It rehearses its
calls, builds a replica of the parent's map and keyframes on ``init``, then answers ``map`` / ``grow`` /
``moments`` messages in order until ``close`` or the parent's end. It ignores SIGINT and SIGTERM: a stop of the
process group is the parent's to handle. A call that raises is answered with its traceback (the parent then stops
using the child)."""

from __future__ import annotations

import pickle
import signal
import traceback

import torch

from slam.engine.map_call import MapJob, run_map_call
from slam.engine.mapper import MapMoments
from slam.engine.wire import pack_state

__all__ = ["serve"]


def serve(conn, cfg, intr, device: str, rehearsal: tuple | None) -> None:
    """The child: rehearses its calls (``rehearsal``: ``(aabb, color, depth, pose)``, :mod:`slam.engine.rehearsal`),
    builds the replica on ``init``, then runs ``map`` / ``grow`` messages in order until ``close``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    from slam.engine.runtime import keep_freed_memory, set_threads
    from slam.model.box_resize import apply_growth
    from slam.model.scene import SceneModel

    set_threads(cfg.threads)
    if cfg.keep_freed_memory:
        keep_freed_memory()
    if rehearsal is not None:
        from slam.engine.rehearsal import rehearse_mapping

        aabb, *frame = rehearsal
        rehearse_mapping(SceneModel(cfg, aabb).to(device), cfg, intr, *(t.to(device) for t in frame))
    conn.send_bytes(pickle.dumps(("hello", None)))  # imported (and rehearsed): the loop need not wait for that
    scene = keyframes = None
    moments = MapMoments()
    gen = torch.Generator()
    while True:
        try:
            kind, body = pickle.loads(conn.recv_bytes())
        except EOFError:  # the parent is gone
            return
        if kind == "close":
            return
        try:
            if kind == "init":
                scene, keyframes = _replica(cfg, device, body)
                gen.set_state(body["gen"])
                moments = MapMoments(body["moments"])
                reply = ("ready", None)
            elif kind == "grow":
                apply_growth(scene, body)
                moments.reset()
                reply = ("grown", None)
            elif kind == "moments":  # asked for by a checkpoint, after the calls sent before it
                state = moments.cpu_state()
                reply = ("moments", None if state is None else {n: pack_state(st) for n, st in state.items()})
            else:  # "map"
                reply = ("done", _map_call(body, scene, keyframes, cfg, intr, device, gen, moments))
        except Exception:  # noqa: BLE001 - the parent re-raises it with this traceback
            reply = ("error", traceback.format_exc())
        try:
            conn.send_bytes(pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL))
        except OSError:  # the parent is gone (killed mid-call): nobody is left to answer
            return


def _map_call(body: tuple, scene, keyframes, cfg, intr, device: str, gen: torch.Generator, moments) -> dict:
    """One ``map`` message: the call, its keyframe, and what the parent mirrors (the map it left, the random
    stream, the keyframes' frames and BA poses)."""
    k, color, depth, pose, first, keyframe, iters = body
    job = MapJob(k, torch.from_numpy(color), torch.from_numpy(depth), pose, first, keyframe, iters)
    res, seconds, snapshot, _ = run_map_call(job, scene, keyframes, cfg, intr, gen, moments, device=device,
                                             snapshot=pack_state)
    res.pose = res.pose.cpu()
    return {"result": res, "seconds": seconds, "snapshot": snapshot, "gen": gen.get_state(),
            "poses": keyframes.poses() if len(keyframes) else torch.zeros(0, 7),
            "indices": [kf.index for kf in keyframes.frames]}


def _replica(cfg, device: str, body: dict):
    """``(scene, keyframes)``: the child's replica of the parent's map and keyframe store from an ``init`` message."""
    from slam.engine.keyframes import Keyframe, KeyframeStore
    from slam.model.box_resize import load_scene_state
    from slam.model.scene import SceneModel

    scene = SceneModel(cfg, body["aabb"]).to(device)
    load_scene_state(scene, body["scene"])
    keyframes = KeyframeStore.for_mapping(cfg.mapping)
    for k, color, depth, pose in body["keyframes"]:
        keyframes.add(Keyframe(k, color, depth, pose), drop=False)  # the parent's are the ones kept
    return scene, keyframes


