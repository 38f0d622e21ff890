"""Run checkpoints: everything a SLAM run needs to go on from where it stopped, in the scene's own checkpoint.

``checkpoint.pt`` of a run folder is a :func:`tdfields.save` checkpoint of the scene (config, state_dict, poses,
bounds, keyframes, as :mod:`slam.run.outputs` always wrote it) whose ``extra["run"]`` holds the loop's state: the
position to go on from, the per-frame state (:class:`slam.engine.system.RunState`), the keyframes' positions and
BA-refined poses, the random states (torch, numpy, the tracker's and the mapper's generators) and, in parallel
mode, the tracker's copy of the map and the mapping calls it has not applied yet. Keyframe images are not stored:
they are read again from the dataset (deterministically the same), so a checkpoint stays a few MB whatever the
sequence length; the dataset's fingerprint (frame counts, every selected frame's file names and sizes) must match
on resume, and so must the kind of device the run computed on (``device_type``: cpu or cuda).

Written with a temporary name, flushed to the disk and renamed (:mod:`slam.files`), so a kill, a power loss or a
full disk while writing leaves the previous checkpoint intact; the one before it is kept as ``checkpoint.prev.pt``
(a hard link, no copy), so a checkpoint damaged after it was written (a truncated copy, a failing disk) still
leaves one to resume from. ``--resume`` refuses a checkpoint whose config is not the run folder's ``config.yaml``
(a new run started into the folder and killed before its first checkpoint), naming the keys that differ.
"""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import torch

from slam.config.load import differing_keys, flatten
from slam.errors import SlamInputError
from slam.files import replacing

RUN_FORMAT = "lrslam-run/1"

log = logging.getLogger("slam")


def checkpoint_extra(run) -> dict:
    """What a scene checkpoint records of a run (``run``: a :class:`slam.engine.view.RunView`): poses, frames,
    bounds, intrinsics, keyframes, the visibility hull's points and the voxels of observed depth (so ``lrslam mesh``
    needs no data)."""
    from slam.model.mesher import run_hull_points, run_observed

    kfs = run.keyframes()
    observed = run_observed(run, kfs)
    return {
        "poses": torch.from_numpy(run.map_poses()).float(),
        "frame_indices": list(run.indices),
        "timestamps": [float(t) for t in run.timestamps] if run.timestamps is not None else [],
        "bound": run.bound,
        "marching_cubes_bound": [list(map(float, r)) for r in run.mc_bound],
        "aabb": run.aabb.tolist(),
        "intrinsics": run.intrinsics.as_dict(),
        "keyframe_indices": [int(run.indices[k]) for k in kfs.positions],
        "keyframe_poses": torch.from_numpy(kfs.poses).float(),
        "hull_points": torch.from_numpy(run_hull_points(run, kfs)).float(),
        "observed_voxels": torch.from_numpy(observed.voxels).int(),
        "observed_voxel_size": observed.size,
    }


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
    run = system.state_dict()  # waits for a mapping call in progress: the scene and keyframes are its until then
    extra = checkpoint_extra(system.view())
    # the kind of device, not its number: cuda:0 and cuda:1 compute the same numbers, the CPU and a GPU do not
    extra["run"] = {"format": RUN_FORMAT, "next": len(system.state.est), "device_type": system.device.type, **run}
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
        raise SlamInputError(f"{exc}{_previous_hint(path)}") from None


def _previous_hint(path: Path) -> str:
    """How to resume from the checkpoint kept before ``path`` ("" when there is none)."""
    prev = previous_path(path)
    if not prev.is_file():
        return ""
    return (f"; the checkpoint before it is kept: mv {prev} {path} and resume again (it goes on from an earlier "
            "frame, to the same result)")


def load_run(path: Path, cfg=None) -> dict:
    """The checkpoint at ``path`` (a dict as :func:`tdfields.load` returns).

    Args:
        cfg: the run folder's config (``config.yaml``); the checkpoint must have been written under it
            (:data:`RESUME_KEYS` may differ; ``device`` only within the recorded kind: cuda:0 for cuda:1).

    Raises:
        SlamInputError: the checkpoint is missing, unreadable (truncated, empty), holds no run state, was
            written under another config, or computed on another kind of device.
    """
    path = Path(path)
    ckpt = _read(path)
    run = ckpt.get("extra", {}).get("run")
    if not isinstance(run, dict) or run.get("format") != RUN_FORMAT:
        found = run.get("format") if isinstance(run, dict) else None
        raise SlamInputError(f"{path}: this checkpoint holds no resumable run state of format {RUN_FORMAT} "
                             f"(found {found or 'none'}: written by another version?)")
    _check_finite(path, ckpt)
    if cfg is not None:
        _check_device(path, run, cfg.device)
        written = ckpt.get("config") or {}
        added = sorted(set(flatten(cfg.to_dict())) - set(flatten(written))) if written else []
        if added:  # keys this version has and the checkpoint's did not: they keep their defaults
            log.warning("%s was written by an earlier version; keys it did not have take their defaults: %s", path,
                        ", ".join(f"{k}={flatten(cfg.to_dict())[k]!r}" for k in added))
        diff = config_differences(written, cfg.to_dict(), ignore=tuple(added))
        if diff:
            raise SlamInputError(
                f"{path} was written under another config than {path.parent / 'config.yaml'} ({'; '.join(diff[:4])}"
                f"{'; ...' if len(diff) > 4 else ''}): was a new run started into this folder? Run it again "
                "without --resume, or into another --out")
    return ckpt


def _check_device(path: Path, run: dict, device: str) -> None:
    """Refuse to go on on another kind of device than the run computed on (``run["device_type"]``; a checkpoint
    without it, from before it was recorded, is not checked): the CPU and a GPU round differently, so the resumed
    run would not end at the uninterrupted run's trajectory, which a resume promises."""
    was, now = run.get("device_type"), torch.device(device).type
    if was is not None and was != now:
        raise SlamInputError(f"{path} was computed on {was} and this resume would go on on {now} (device = "
                             f"{device!r}): {was} and {now} compute different numbers, so the resumed trajectory "
                             f"would not be the uninterrupted run's; resume with --device {was}")


def _maps(ckpt: dict):
    """``(where, name, tensor)`` for every tensor of the maps a checkpoint holds: the mapper's, the tracker's copy,
    the maps of the calls still pending, and the carried Adam moments."""
    run = ckpt["extra"]["run"]
    trees = [("map", ckpt.get("state_dict")), ("tracker's map", run.get("track_scene"))]
    trees += [(f"map of the pending call of frame {p.get('k')}", p.get("snapshot")) for p in run.get("pending") or []
              if isinstance(p, dict)]
    for where, tree in trees:
        for name, t in (tree or {}).items():
            yield where, name, t
    for name, state in (run.get("moments") or {}).items():
        for part, t in state.items():
            yield "carried Adam moments", f"{name} ({part})", t


def _check_finite(path: Path, ckpt: dict) -> None:
    """Refuse a checkpoint whose maps hold NaN or infinity (a damaged or hand-edited file): resumed, every later
    mapping step would read them and the run would go on silently wrong."""
    for where, name, t in _maps(ckpt):
        if isinstance(t, torch.Tensor) and t.is_floating_point() and not bool(torch.isfinite(t).all()):
            bad = int((~torch.isfinite(t)).sum())
            raise SlamInputError(f"{path}: the {where} holds {bad} non-finite value(s) in {name}"
                                 f"{_previous_hint(path)}; or run again without --resume")


#: keys a resumed run may change: they decide where the run computes and when it stops or writes, never what it
#: computes (the keyframe spill folder is scratch: a run folder moved to another machine names its own)
RESUME_KEYS = ("device", "mapper_process", "preload_kernels", "data.max_bad_fraction", "data.prefetch",
               "data.prefetch_in", "checkpoint_every", "checkpoint_interval_s", "mapping.keyframe_spill_dir")


def config_differences(a: dict, b: dict, ignore: tuple[str, ...] = ()) -> list[str]:
    """``"key: A vs B"`` for every dotted key whose value differs between two config dicts (outside
    :data:`RESUME_KEYS` and ``ignore``)."""
    fa, fb = flatten(a), flatten(b)
    return [f"{k}: {fa.get(k)!r} vs {fb.get(k)!r}" for k in differing_keys(a, b, RESUME_KEYS + tuple(ignore))]


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
    system.load_state_dict(run, ckpt["state_dict"])
    return int(run["next"])
