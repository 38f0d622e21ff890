"""Run checkpoints: everything a SLAM run needs to go on from where it stopped, in the scene's own checkpoint.

``checkpoint.pt`` of a run folder is a :func:`tdfields.save` checkpoint of the scene (config, state_dict, poses,
bounds, keyframes, as :mod:`slam.run.outputs` always wrote it) whose ``extra["run"]`` holds the loop's state: the
position to go on from, the per-frame state (:class:`slam.engine.system.RunState`), the keyframes' positions and
BA-refined poses, the random states (torch, numpy, the tracker's and the mapper's generators) and, in parallel
mode, the tracker's copy of the map and the mapping calls it has not applied yet. Keyframe images are not stored:
they are read again from the dataset (deterministically the same), so a checkpoint stays a few MB whatever the
sequence length; the dataset's fingerprint (frame count and file names) must match on resume.

Written with a temporary name, flushed to the disk and renamed (:mod:`slam.files`), so a kill, a power loss or a
full disk while writing leaves the previous checkpoint intact; the one before it is kept as ``checkpoint.prev.pt``
(a hard link, no copy), so a checkpoint damaged after it was written (a truncated copy, a failing disk) still
leaves one to resume from. ``--resume`` refuses a checkpoint whose config is not the run folder's ``config.yaml``
(a new run started into the folder and killed before its first checkpoint), naming the keys that differ.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

import numpy as np
import torch

from slam.config.load import differing_keys, flatten
from slam.errors import SlamInputError
from slam.files import replacing
from slam.engine.keyframes import Keyframe
from slam.engine.map_worker import MapDone, MapJob
from slam.engine.mapper import MapResult

RUN_FORMAT = "lrslam-run/1"


def fingerprint(system) -> dict:
    """What must not change between a run and its resume: the frames processed and their files."""
    ds = system.ds
    names = []
    for attr in ("color_paths", "depth_paths"):
        paths = getattr(ds, attr, None)
        if paths:
            names += [Path(paths[i]).name for i in (system.indices[0], system.indices[-1])]
    return {"frames": len(system.indices), "dataset_frames": len(ds), "files": names}


def _numpy_state() -> dict:
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos), "has_gauss": int(has_gauss),
            "cached": float(cached)}


def _set_numpy_state(s: dict) -> None:
    np.random.set_state(("MT19937", s["keys"].numpy().astype(np.uint32), s["pos"], s["has_gauss"], s["cached"]))


def run_state(system) -> dict:
    """The loop's state as plain tensors and numbers (``torch.load(weights_only=True)`` can read it back).

    Call between frames; pending mapping calls are waited for (not applied: the schedule applies them)."""
    mapper = system.mapper
    pending = []
    for k, item in mapper._queue:
        done = item if isinstance(item, MapDone) else item.result()
        pending.append({"k": done.job.k, "pose": done.job.pose.cpu(), "first": done.job.first,
                        "keyframe": done.job.keyframe, "seconds": done.seconds,
                        "result": {"pose": done.result.pose.cpu(), "window": list(done.result.window),
                                   "loss": float(done.result.loss), "ok": bool(done.result.ok),
                                   "skipped": int(done.result.skipped)},
                        "snapshot": done.snapshot})
    st = dataclasses.asdict(system.state)
    st["est"] = torch.stack(system.state.est) if system.state.est else torch.zeros(0, 7)
    out = {
        "format": RUN_FORMAT,
        "next": len(system.state.est),
        "state": st,
        "keyframes": [{"k": kf.index, "pose": kf.pose.clone()} for kf in system.keyframes.frames],
        "keyframes_dropped": system.keyframes.dropped,
        "rng": {"torch": torch.get_rng_state(), "numpy": _numpy_state(), "gen": system.gen.get_state(),
                "map_gen": system.map_gen.get_state()},
        "pending": pending,
        "applied_any": bool(mapper._applied_any),
        "guard": system.guard.state(),
        "track_scene": ({k: v.detach().cpu() for k, v in mapper.track_scene.state_dict().items()}
                        if mapper.parallel else None),
        "fingerprint": fingerprint(system),
    }
    return out


def previous_path(path: Path) -> Path:
    """Where the checkpoint before ``path`` is kept: ``checkpoint.prev.pt`` beside ``checkpoint.pt``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.prev{path.suffix}")


def _keep_previous(path: Path) -> None:
    """Keep the current checkpoint as :func:`previous_path` before it is replaced (a hard link where the
    filesystem has them, else a copy); ``path`` itself stays in place throughout."""
    if not path.is_file():
        return
    prev = previous_path(path)
    tmp = prev.with_name(f".{prev.name}.tmp")
    tmp.unlink(missing_ok=True)
    try:
        os.link(path, tmp)
    except OSError:
        shutil.copy2(path, tmp)
    os.replace(tmp, prev)


def save_checkpoint(system, path: Path) -> None:
    """``checkpoint.pt``: the scene checkpoint with the run state, written atomically and durably.

    Raises:
        SlamOutputError: it could not be written (a full disk); the previous checkpoint is intact.
    """
    import tdfields

    path = Path(path)
    system.mapper.wait_idle()  # the scene and the keyframes are the worker's while a call runs
    extra = system.checkpoint_extra()
    extra["run"] = run_state(system)
    with replacing(path, "checkpoint") as tmp:
        tdfields.save(tmp, system.scene, config=system.cfg.to_dict(), extra=extra)
        _keep_previous(path)


def _read(path: Path) -> dict:
    import tdfields

    try:
        return tdfields.load(path)
    except FileNotFoundError:
        raise SlamInputError(f"{path}: no checkpoint to resume from") from None
    except ValueError as exc:
        prev = previous_path(path)
        hint = ""
        if prev.is_file():
            hint = (f"; the checkpoint before it is kept: mv {prev} {path} and resume again (it goes on from an "
                    "earlier frame, to the same result)")
        raise SlamInputError(f"{exc}{hint}") from None


def load_run(path: Path, cfg=None) -> dict:
    """The checkpoint at ``path`` (a dict as :func:`tdfields.load` returns).

    Args:
        cfg: the run folder's config (``config.yaml``); the checkpoint must have been written under it (the
            device and :data:`RESUME_KEYS` may differ).

    Raises:
        SlamInputError: the checkpoint is missing, unreadable (truncated, empty), holds no run state, or was
            written under another config.
    """
    path = Path(path)
    ckpt = _read(path)
    run = ckpt.get("extra", {}).get("run")
    if not isinstance(run, dict) or run.get("format") != RUN_FORMAT:
        found = run.get("format") if isinstance(run, dict) else None
        raise SlamInputError(f"{path}: this checkpoint holds no resumable run state of format {RUN_FORMAT} "
                             f"(found {found or 'none'}: written by another version?)")
    if cfg is not None:
        diff = config_differences(ckpt.get("config") or {}, cfg.to_dict())
        if diff:
            raise SlamInputError(
                f"{path} was written under another config than {path.parent / 'config.yaml'} ({'; '.join(diff[:4])}"
                f"{'; ...' if len(diff) > 4 else ''}): was a new run started into this folder? Run it again "
                "without --resume, or into another --out")
    return ckpt


#: keys a resumed run may change: they decide when the run stops or writes, never what it computes
RESUME_KEYS = ("device", "data.max_bad_fraction", "data.prefetch", "checkpoint_every", "checkpoint_interval_s")


def config_differences(a: dict, b: dict) -> list[str]:
    """``"key: A vs B"`` for every dotted key whose value differs between two config dicts (outside
    :data:`RESUME_KEYS`)."""
    fa, fb = flatten(a), flatten(b)
    return [f"{k}: {fa.get(k)!r} vs {fb.get(k)!r}" for k in differing_keys(a, b, RESUME_KEYS)]


def restore(system, ckpt: dict) -> int:
    """Put a freshly built ``system`` (same config and data) into the checkpoint's state; returns the position of
    the next frame to process.

    Raises:
        SlamInputError: the data or the scene do not fit, or the run state misses a part (a damaged checkpoint)."""
    try:
        return _restore(system, ckpt)
    except (KeyError, TypeError, IndexError) as exc:
        raise SlamInputError(f"the checkpoint's run state is incomplete or damaged ({type(exc).__name__}: {exc}); "
                             "resume from checkpoint.prev.pt, or run again without --resume") from None


def _restore(system, ckpt: dict) -> int:
    run = ckpt["extra"]["run"]
    if run["fingerprint"] != fingerprint(system):
        raise SlamInputError(f"the data differ from the checkpointed run's ({run['fingerprint']} vs "
                             f"{fingerprint(system)}): resume with the same data folder and config")
    try:
        with torch.no_grad():
            system.scene.load_state_dict(ckpt["state_dict"])
            if run["track_scene"] is not None:
                system.mapper.track_scene.load_state_dict(run["track_scene"])
    except RuntimeError as exc:  # missing keys or other shapes: not this config's scene
        first = str(exc).strip().splitlines()[0]
        raise SlamInputError(f"the checkpoint's scene does not fit this run's config ({first})") from None
    st = dict(run["state"])
    est = st.pop("est")
    system.state = type(system.state)(**st)
    system.state.est = [p.clone() for p in est]
    system.keyframes.frames.clear()
    system.keyframes.dropped = int(run.get("keyframes_dropped", 0))
    cap = system.keyframes.max_keyframes
    system.keyframes.max_keyframes = 0  # the checkpoint's keyframes are the ones kept: no dropping while restoring
    for kf in run["keyframes"]:
        frame = system.frames.get(kf["k"])
        if not frame.ok:
            raise SlamInputError(f"keyframe {kf['k']} can no longer be read: {frame.error}")
        system.keyframes.add(Keyframe(kf["k"], frame.color.cpu(), frame.depth.cpu(), kf["pose"].clone()))
    system.keyframes.max_keyframes = cap
    if system.state.prev_depth_k >= 0:
        system._prev_depth = system.frames.get(system.state.prev_depth_k).depth
    system.mapper._applied_any = bool(run["applied_any"])
    system.guard.load(run["guard"])
    for p in run["pending"]:
        job = MapJob(p["k"], None, None, p["pose"], p["first"], p["keyframe"])
        r = p["result"]
        res = MapResult(r["pose"], r["window"], r["loss"], r["ok"], r["skipped"])
        system.mapper._queue.append((p["k"], MapDone(job, res, p["seconds"], p["snapshot"])))
    torch.set_rng_state(run["rng"]["torch"])
    _set_numpy_state(run["rng"]["numpy"])
    system.gen.set_state(run["rng"]["gen"])
    system.map_gen.set_state(run["rng"]["map_gen"])
    return int(run["next"])
