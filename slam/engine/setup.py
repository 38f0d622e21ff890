"""Setting a run up: the device, the dataset a config names, the frames it processes, the scene box (automatic or
given), and the data's fingerprint a resumed run must match."""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

import numpy as np
import torch

from slam.config import Config
from slam.engine.frames import readable_depth
from slam.errors import SlamInputError

log = logging.getLogger("slam")


def resolve_device(name: str) -> torch.device:
    """``cpu`` / ``cuda`` / ``cuda:N``; a GPU request without CUDA raises :class:`SlamInputError`."""
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise SlamInputError(f"device '{name}' requested but CUDA is not available on this machine; use --device cpu")
        idx = int(name.split(":")[1]) if ":" in name else 0
        if idx >= torch.cuda.device_count():
            raise SlamInputError(f"device '{name}' requested but only {torch.cuda.device_count()} GPU(s) exist")
    elif name != "cpu":
        raise SlamInputError(f"device must be cpu or cuda, got '{name}'")
    return torch.device(name)


def check_spill_dir(cfg: Config) -> None:
    """A fresh run that will spill keyframe images (``mapping.keyframes_in_memory`` > 0) into
    ``mapping.keyframe_spill_dir`` must find that folder writable; SlamInputError otherwise.

    Only a fresh run is checked: a resumed run (a run folder moved to another machine, its scratch cleaned) keeps
    the images in memory when the folder cannot be written (:class:`slam.engine.keyframes.KeyframeStore`, the same
    bits either way), and may name another folder with ``--resume OUT mapping.keyframe_spill_dir=DIR``."""
    spill = cfg.mapping.keyframe_spill_dir
    if not spill or cfg.mapping.keyframes_in_memory == 0:  # the system's temporary folder, or never spilled
        return
    folder = os.path.expanduser(spill)
    why = ("is not a folder" if not os.path.isdir(folder) else
           "is not writable" if not os.access(folder, os.W_OK | os.X_OK) else None)
    if why:
        raise SlamInputError(f"config key 'mapping.keyframe_spill_dir' = {spill!r} {why} (keyframe images past "
                             f"mapping.keyframes_in_memory = {cfg.mapping.keyframes_in_memory} go there; \"\" uses "
                             "the system's temporary folder, keyframes_in_memory=0 keeps them all in memory)")


def load_data(cfg: Config):
    """Open the dataset the config names (when ``data.path`` is null the bundled synthetic sequence, the room or
    ``data.options.scene: walk``, generated with the generator options ``data.options`` gives: seed, frames, ...).

    Raises:
        SlamInputError: a ``data.options`` key the dataset kind does not take (checked before any folder is read
            or sequence generated), a missing or foreign folder, or data the loader cannot read."""
    from slam.data import detect_layout, load_dataset
    from slam.data.registry import container_kind, dataset_kind

    path = cfg.data.path
    # a ROS bag holds a recording of any camera: a preset of any kind reads it as data.kind auto would
    data_kind = "auto" if path is not None and container_kind(path) else cfg.data.kind
    # the layout a folder of the named dataset is detected as (the synthetic room's is Replica's)
    kind = "auto" if data_kind == "auto" else dataset_kind(data_kind).detected_as
    options = dict(cfg.data.options)
    if data_kind != "auto":
        check_data_options(data_kind, options, path)
    synthetic = data_kind == "synthetic"
    scene = options.pop("scene", "room") if synthetic else "room"
    generator = {k: options.pop(k) for k in list(options) if k in GENERATOR_OPTIONS} if synthetic else {}
    if path is None:
        if kind not in ("auto", dataset_kind("synthetic").detected_as):
            raise SlamInputError(f"preset '{cfg.name}' reads {kind} data: pass its folder with --data PATH")
        path = str(_synthetic_sequence(scene, cfg.data.max_frames, cfg.data.stride, generator))
    p = Path(path).expanduser()
    if not p.exists():
        raise SlamInputError(f"data not found: {p} (a dataset folder, a ROS 1 .bag file or a ROS 2 bag folder)")
    found = detect_layout(p)
    if kind != "auto" and found != kind:
        raise SlamInputError(f"preset '{cfg.name}' expects {kind} data but {p} looks like {found} data "
                             f"(pick a {found} preset or data.kind=auto)")
    if data_kind == "auto":
        check_data_options(found, options, path)
    try:
        ds = load_dataset(p, kind=found, **options)
    except SlamInputError:
        raise
    except (ValueError, FileNotFoundError, KeyError, OSError, TypeError) as exc:
        raise SlamInputError(f"{p}: cannot be read as {found} data: {exc}") from None
    if len(ds) == 0:
        raise SlamInputError(f"{p}: the dataset has no frames")
    return ds


#: ``data.options`` of a synthetic preset that set how its sequence is generated: the fields of
#: :class:`slam.data.synthetic.SynthConfig` (``lrslam synth``'s options) but ``scene``, which
#: ``data.options.scene`` chooses
GENERATOR_OPTIONS = ("seed", "frames", "height", "width", "focal_scale", "depth_noise_sigma", "sensor_holes",
                     "color_noise_sigma", "loop_frames", "path_radius", "supersample")


def check_data_options(kind: str, options: dict, path: str | None) -> None:
    """Every ``data.options`` key must be an option of the dataset ``kind`` (a name in
    :data:`slam.data.DATASETS`): its loader's (:attr:`~slam.data.registry.DatasetKind.options`), and for
    ``synthetic`` also ``scene`` and, when the sequence is generated (``path`` None), :data:`GENERATOR_OPTIONS`
    with the types of :class:`~slam.data.synthetic.SynthConfig`'s fields.

    Raises:
        SlamInputError: one line naming the key and the options the kind takes."""
    from slam.data.registry import dataset_kind
    from slam.data.synthetic import SynthConfig

    accepted = set(dataset_kind(kind).options)
    if kind == "synthetic":
        accepted |= {"scene", *GENERATOR_OPTIONS}
    for key, value in options.items():
        if key not in accepted:
            raise SlamInputError(f"config key 'data.options.{key}' is not an option of {kind} data; it takes "
                                 f"{', '.join(sorted(accepted))}")
        if kind == "synthetic" and key in GENERATOR_OPTIONS:
            if path is not None:
                raise SlamInputError(f"config key 'data.options.{key}' sets how the synthetic sequence is generated: "
                                     f"it does not apply to a data folder (data.path = {path!r}; generate one with "
                                     "lrslam synth, or leave data.path null)")
            default = getattr(SynthConfig(), key)
            # bool first: YAML's true is an int to Python, and an int is a fine float
            ok, want = ((isinstance(value, bool), "true or false") if isinstance(default, bool) else
                        (isinstance(value, int) and not isinstance(value, bool), "an integer")
                        if isinstance(default, int) else
                        (isinstance(value, (int, float)) and not isinstance(value, bool), "a number"))
            if not ok:
                shown = str(value).lower() if isinstance(value, bool) else repr(value)
                raise SlamInputError(f"config key 'data.options.{key}' = {shown} must be {want} (as "
                                     f"slam.data.synthetic.SynthConfig.{key}, default {default!r})")


def _synthetic_sequence(scene: str, max_frames: int | None, stride: int, generator: dict | None = None):
    """The bundled sequence of ``data.options.scene`` (``room``, the default, or ``walk``), generated with the
    :data:`GENERATOR_OPTIONS` in ``generator`` (none: the scene's defaults, the cached default sequences). Of the
    walk only the frames the run reads are generated (its first ``max_frames * stride``, unless ``frames`` is
    given; an excerpt's frames equal the walk's)."""
    from slam.data.synthetic import SCENES, WALK_FRAMES, SynthConfig, default_sequence, walk_config, walk_sequence

    if scene not in SCENES:
        raise SlamInputError(f"config key 'data.options.scene' = {scene!r}: must be one of {', '.join(SCENES)}")
    if scene == "walk":
        frames = WALK_FRAMES if max_frames is None else min(WALK_FRAMES, max_frames * stride)
        if not generator:
            return walk_sequence(frames)
        return default_sequence(cfg=walk_config(**{"frames": frames, **generator}))
    if not generator:
        return default_sequence()
    return default_sequence(cfg=SynthConfig(**generator))


def check_edges(cfg: Config, height: int, width: int) -> None:
    """``tracking.ignore_edge`` must leave pixels to track in the working image (it is only known once the first
    frame is read, so the config loader cannot check it)."""
    rows, cols = cfg.tracking.ignore_edge
    if 2 * rows >= height or 2 * cols >= width:
        raise SlamInputError(
            f"config key 'tracking.ignore_edge' = {cfg.tracking.ignore_edge} leaves no pixel to track in the "
            f"{height}x{width} working image: rows must be < {(height + 1) // 2}, columns < {(width + 1) // 2}")


def initial_pose(gt: torch.Tensor | None, indices: list[int]) -> tuple[torch.Tensor, str]:
    """The first frame's ``[4, 4]`` camera-to-world and where it comes from: its ground truth ``gt[0]`` when finite
    (ESLAM pins frame 0 to it), else the first finite ground-truth pose of the sequence (ScanNet marks some as
    invalid), else the identity. ``gt``: ``[N, 4, 4]`` of the selected frames, or None."""
    if gt is not None:
        ok = torch.isfinite(gt).flatten(1).all(1)
        if bool(ok[0]):
            return gt[0].clone(), "ground truth"
        if bool(ok.any()):
            j = int(torch.nonzero(ok)[0])
            return gt[j].clone(), f"ground truth of frame {indices[j]} (frame {indices[0]}'s is invalid)"
    return torch.eye(4), "identity (no ground truth)"


def frame_indices(n: int, cfg: Config) -> list[int]:
    idx = list(range(0, n, max(cfg.data.stride, 1)))
    if cfg.data.max_frames:
        idx = idx[: cfg.data.max_frames]
    return idx


def auto_bound(depths: list[torch.Tensor], c2w0: torch.Tensor, percentile: float, margin: float) -> list[list[float]]:
    """Scene box from the first frames' depth (``scene.bound: auto``).

    A cube centred on the first camera whose half-size is the ``percentile``-th percentile of the valid depth
    of the given frames plus ``margin`` metres. It holds everything those frames see from any orientation at
    the start, so a camera that mostly rotates (or moves less than ``margin``) stays inside without hand-tuned
    boxes. Lengths in metres.
    """
    vals = torch.cat([d[d > 0].flatten().float().cpu() for d in depths])
    if vals.numel() == 0:
        raise SlamInputError("bound=auto: the first frames have no valid depth; give scene.bound explicitly")
    r = float(np.percentile(vals.numpy(), percentile)) + margin
    c = c2w0[:3, 3].double().tolist()
    return [[c[a] - r, c[a] + r] for a in range(3)]


def scene_bound(cfg: Config, ds, indices: list[int], first_depth, c2w0: torch.Tensor) -> list[list[float]]:
    """The run's scene bound ``[3, 2]`` (metres): ``scene.bound`` as given, or with ``auto`` :func:`auto_bound` of the
    first ``scene.bound_auto_frames`` selected frames' depth (``first_depth``: the first frame's, already read)."""
    if cfg.scene.bound != "auto":
        return [list(map(float, r)) for r in cfg.scene.bound]
    k = max(1, min(cfg.scene.bound_auto_frames, len(indices)))
    depths = [first_depth] + [readable_depth(ds, indices[i]) for i in range(1, k)]
    bound = auto_bound([d for d in depths if d is not None], c2w0, cfg.scene.bound_auto_percentile,
                       cfg.scene.bound_auto_margin)
    log.info("bound=auto -> %s", [[round(v, 3) for v in r] for r in bound])
    return bound


#: the fingerprint's form: 2 adds every selected frame's file names and sizes (20b7b9c's, without "form", held the
#: frame counts and the first and last file names only)
FINGERPRINT_FORM = 2


def _frame_files(ds, indices: list[int]) -> list[Path]:
    """The colour and depth files of the selected frames, colour first, in frame order, then the files a
    container dataset reads its frames from (``source_files``: a ROS bag's)."""
    return [Path(paths[i]) for paths in (getattr(ds, "color_paths", None), getattr(ds, "depth_paths", None)) if paths
            for i in indices] + [Path(p) for p in getattr(ds, "source_files", ())]


def _digest(items) -> str:
    return hashlib.sha256("\n".join(map(str, items)).encode()).hexdigest()[:32]


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:  # gone since the dataset was opened: a bad frame, the same when resumed on the same data
        return -1


def _old_fingerprint(ds, indices: list[int]) -> dict:
    """20b7b9c's fingerprint: frame counts and the first and last frames' file names."""
    names = []
    for attr in ("color_paths", "depth_paths"):
        paths = getattr(ds, attr, None)
        if paths:
            names += [Path(paths[i]).name for i in (indices[0], indices[-1])]
    return {"frames": len(indices), "dataset_frames": len(ds), "files": names}


def data_fingerprint(ds, indices: list[int]) -> dict:
    """What must not change between a run and its resume: the frames processed and their files.

    ``{"form": 2, "frames", "dataset_frames", "files": the first and last frames' colour and depth file names,
    "names": a digest of every selected frame's file names, "sizes": one of their sizes in bytes}``. Sizes, not
    contents: a checkpoint is written every minute and a sequence holds thousands of images (GBs to read each
    time), while a file replaced by another image has another size in practice (compressed PNG / JPEG). A few
    hundred bytes whatever the sequence length; one ``stat`` per file."""
    files = _frame_files(ds, indices)
    return {"form": FINGERPRINT_FORM, **_old_fingerprint(ds, indices), "names": _digest(p.name for p in files),
            "sizes": _digest(_size(p) for p in files)}


def fingerprint_mismatch(stored: dict, ds, indices: list[int]) -> str | None:
    """Why the data ``ds`` / ``indices`` are not those a checkpoint's fingerprint ``stored`` was taken of (None
    when they are). A fingerprint of 20b7b9c's form (no ``form``) is compared on what it holds, so its
    checkpoints stay resumable."""
    old = _old_fingerprint(ds, indices)
    for key, what in (("frames", "frames selected"), ("dataset_frames", "frames in the dataset")):
        if stored.get(key) != old[key]:
            return f"{stored.get(key)} {what} at the checkpoint, {old[key]} now"
    if stored.get("files") != old["files"]:
        return f"first and last files {stored.get('files')} at the checkpoint, {old['files']} now"
    if "form" not in stored:
        return None
    now = data_fingerprint(ds, indices)
    if stored.get("names") != now["names"]:
        return "the file names of the selected frames differ (a frame renamed, added or removed)"
    if stored.get("sizes") != now["sizes"]:
        return "the file sizes of the selected frames differ (a frame replaced)"
    return None


def fingerprints_match(stored: dict, ds, indices: list[int]) -> bool:
    """Whether ``ds`` / ``indices`` are the data of a checkpoint's fingerprint (see :func:`fingerprint_mismatch`)."""
    return fingerprint_mismatch(stored, ds, indices) is None
