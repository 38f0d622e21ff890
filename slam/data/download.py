"""Fetch a public RGB-D dataset into the layout the loaders read (``lrslam download``).

::

    replica [SCENE]   NICE-SLAM's Replica.zip (all 8 scenes)  -> DIR/Replica/<scene>/{results/, traj.txt}
    tum SEQUENCE      TUM RGB-D rgbd_dataset_freiburgN_<name>.tgz -> DIR/rgbd_dataset_freiburgN_<name>/
    7scenes SCENE     Microsoft 7-Scenes <scene>.zip, whose seq-XX.zip are unpacked too
                                                               -> DIR/7scenes/<scene>/seq-XX/frame-*
    scannet           access needs the ScanNet Terms of Use: prints where to ask, downloads nothing

An archive is downloaded beside its target (resumable, :mod:`slam.data.archive`), unpacked into a hidden
folder and renamed into place, so a target folder exists only once it is complete and a rerun is a no-op.
``mirror`` (or ``$LRSLAM_DOWNLOAD_MIRROR``) replaces the publisher's base address: the archive is then fetched
from ``<mirror>/<path>``, where ``path`` is ``Replica.zip``, ``freiburg1/rgbd_dataset_freiburg1_rpy.tgz`` or
``chess.zip``.
"""

from __future__ import annotations

import difflib
import os
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

from slam.data import archive, registry
from slam.errors import SlamInputError

__all__ = ["DATASETS", "KNOWN_CHECKSUMS", "MIRROR_ENV", "SCANNET_ACCESS", "Source", "fetch", "resolve",
           "run_commands"]

MIRROR_ENV = "LRSLAM_DOWNLOAD_MIRROR"
#: the names `lrslam download` takes (slam.data.registry: the fetched ones, then those given on request)
DATASETS = tuple(sorted((name for name, d in registry.DATASETS.items() if d.download),
                        key=lambda name: registry.DATASETS[name].download == "request"))

REPLICA_URL = "https://cvg-data.inf.ethz.ch/nice-slam/data"
TUM_URL = "https://cvg.cit.tum.de/rgbd/dataset"
SEVEN_SCENES_URL = "http://download.microsoft.com/download/2/8/5/28564B23-0828-408F-8631-23B1EFF1DAC8"

REPLICA_SCENES = ("room0", "room1", "room2", "office0", "office1", "office2", "office3", "office4")
SEVEN_SCENES = ("chess", "fire", "heads", "office", "pumpkin", "redkitchen", "stairs")
#: the TUM RGB-D sequences with ground truth, per sensor (names after ``rgbd_dataset_freiburgN_``)
TUM_SEQUENCES = {
    1: ("xyz", "rpy", "360", "floor", "desk", "desk2", "room", "plant", "teddy"),
    2: ("xyz", "rpy", "360_hemisphere", "360_kidnap", "desk", "large_no_loop", "large_with_loop", "pioneer_360",
        "pioneer_slam", "pioneer_slam2", "pioneer_slam3", "desk_with_person", "coke", "dishes", "flowerbouquet",
        "flowerbouquet_brownbackground", "metallic_sphere", "metallic_sphere2"),
    3: ("long_office_household", "nostructure_notexture_far", "nostructure_notexture_near_withloop",
        "nostructure_texture_far", "nostructure_texture_near_withloop", "structure_notexture_far",
        "structure_notexture_near", "structure_texture_far", "structure_texture_near", "sitting_static",
        "sitting_xyz", "sitting_halfsphere", "sitting_rpy", "walking_static", "walking_xyz", "walking_halfsphere",
        "walking_rpy", "cabinet", "large_cabinet", "teddy"),
}

#: archive file name -> (hashlib algorithm, hex digest), for archives whose publisher gives a checksum. None
#: of the three publishers does today; ``--sha256`` pins one by hand.
KNOWN_CHECKSUMS: dict[str, tuple[str, str]] = {}

SCANNET_ACCESS = """\
ScanNet is not downloaded by `lrslam download`: its authors give access only to people who accept the
ScanNet Terms of Use. To get it:
  1. go to http://www.scan-net.org/, fill in the ScanNet Terms of Use form and send it as the page says;
  2. the answer brings ScanNet's download script: fetch a scene's .sens file (e.g. scene0000_00) and extract it
     with ScanNet's SensReader into <scene>/color/ depth/ pose/ intrinsic/;
  3. lrslam run --config scannet/scene0000 --data data/scannet/scene0000_00 --device cuda
Folder layout: docs/data.md (ScanNet)."""


@dataclass(frozen=True)
class Source:
    """One downloadable archive and where it ends up.

    ``path``: the archive's path under the publisher's base URL ``base`` (and under a mirror); ``member``: the
    folder at the archive's top level; ``target``: where that folder goes, relative to ``--to``; ``data``: the
    folder ``lrslam run --data`` reads, relative to ``--to``.
    """

    dataset: str
    base: str
    path: str
    member: str
    target: str
    data: str

    @property
    def archive_name(self) -> str:
        """The archive's file name (the last part of :attr:`path`), also its name under ``--to``."""
        return self.path.rsplit("/", 1)[-1]

    def url(self, mirror: str | None = None) -> str:
        """The archive's address: the publisher's, or ``mirror`` followed by :attr:`path`."""
        return f"{(mirror or self.base).rstrip('/')}/{self.path}"


def _unknown(kind: str, name: str, valid) -> SlamInputError:
    """The one-line error for an unknown ``name`` of ``kind``: the closest valid name, then all of them."""
    close = difflib.get_close_matches(name, list(valid), n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    return SlamInputError(f"unknown {kind} {name!r}{hint}; expected one of: {', '.join(valid)}")


def _tum_names() -> list[str]:
    """Every known TUM sequence as ``frN_<name>``."""
    return [f"fr{n}_{seq}" for n, seqs in TUM_SEQUENCES.items() for seq in seqs]


def tum_sequence(name: str) -> tuple[int, str]:
    """``(sensor 1..3, sequence)`` of a TUM name: ``fr1_rpy``, ``freiburg1_rpy``, ``rgbd_dataset_freiburg1_rpy``,
    ``fr1/rpy``; SlamInputError listing the valid names otherwise."""
    m = re.fullmatch(r"(?:rgbd_dataset_)?(?:freiburg|fr)([123])[_/](\w+?)(?:\.tgz)?", name.strip().lower())
    if not m or m.group(2) not in TUM_SEQUENCES[int(m.group(1))]:
        short = f"fr{m.group(1)}_{m.group(2)}" if m else name
        raise _unknown("TUM sequence", short, _tum_names())
    return int(m.group(1)), m.group(2)


def resolve(dataset: str, scene: str | None) -> Source:
    """The :class:`Source` for ``dataset`` (``replica``, ``tum``, ``7scenes``) and ``scene`` (a Replica scene,
    default room0; a TUM sequence; a 7-Scenes scene). SlamInputError on an unknown or missing name."""
    dataset = dataset.lower()
    if dataset == "replica":
        scene = scene or "room0"
        if scene not in REPLICA_SCENES:
            raise _unknown("Replica scene", scene, REPLICA_SCENES)
        return Source("replica", REPLICA_URL, "Replica.zip", "Replica", "Replica", f"Replica/{scene}")
    if dataset == "tum":
        if not scene:
            raise SlamInputError(f"tum needs a sequence name, e.g. fr1_rpy; one of: {', '.join(_tum_names())}")
        n, seq = tum_sequence(scene)
        folder = f"rgbd_dataset_freiburg{n}_{seq}"
        return Source("tum", TUM_URL, f"freiburg{n}/{folder}.tgz", folder, folder, folder)
    if dataset == "7scenes":
        if not scene:
            raise SlamInputError(f"7scenes needs a scene: {', '.join(SEVEN_SCENES)}")
        if scene.lower() not in SEVEN_SCENES:
            raise _unknown("7-Scenes scene", scene, SEVEN_SCENES)
        scene = scene.lower()
        return Source("7scenes", SEVEN_SCENES_URL, f"{scene}.zip", scene, f"7scenes/{scene}", f"7scenes/{scene}")
    if dataset == "scannet":
        raise SlamInputError("ScanNet needs the authors' permission: `lrslam download scannet` says how to ask")
    raise _unknown("dataset", dataset, DATASETS)


def _mirror(mirror: str | None) -> str | None:
    """The base URL to use instead of the publisher's: ``mirror``, else ``$LRSLAM_DOWNLOAD_MIRROR``, else None."""
    mirror = mirror or os.environ.get(MIRROR_ENV) or None
    if mirror is not None and not re.match(r"https?://", mirror):
        raise SlamInputError(f"mirror {mirror!r} must be an http:// or https:// address")
    return mirror


def _unpack_into_place(src: Source, arc: Path, target: Path) -> None:
    """Unpack ``arc`` into a hidden folder beside ``target``, unpack 7-Scenes' inner ``seq-XX.zip`` files too,
    then rename the archive's top folder to ``target`` (so ``target`` exists only when complete)."""
    tmp = target.parent / f".{target.name}.unpacking"
    archive.remove_tree(tmp)  # a crash mid-unpack leaves it behind
    try:
        archive.unpack(arc, tmp)
        top = tmp / src.member
        if src.dataset == "7scenes" and not top.is_dir() and any(tmp.glob("seq-*.zip")):
            top = tmp  # the sequences at the archive's top level instead of in <scene>/
        if not top.is_dir():
            found = sorted(p.name for p in tmp.iterdir())
            raise SlamInputError(f"{arc}: expected a top-level folder {src.member!r}, found {found}")
        if src.dataset == "7scenes":
            for inner in sorted(top.glob("seq-*.zip")):
                _unpack_sequence(inner, top)
        top.replace(target)
    finally:
        archive.remove_tree(tmp)


def _unpack_sequence(inner: Path, scene_dir: Path) -> None:
    """Unpack a 7-Scenes ``seq-XX.zip`` to ``scene_dir/seq-XX/`` and delete it; the zip may or may not wrap
    its frames in a ``seq-XX/`` folder."""
    import zipfile

    seq = inner.stem
    with zipfile.ZipFile(inner) as zf:
        wrapped = all(n == f"{seq}/" or n.startswith(f"{seq}/") for n in zf.namelist())
    archive.unpack(inner, scene_dir if wrapped else scene_dir / seq)
    inner.unlink()


def _data_folder(src: Source, root: Path) -> Path:
    """The folder to pass to ``lrslam run --data``: a 7-Scenes scene's first sequence, else ``src.data``."""
    data = root / src.data
    if src.dataset == "7scenes":
        seqs = sorted(p for p in data.glob("seq-*") if p.is_dir())
        if not seqs:
            raise SlamInputError(f"{data}: no seq-XX folders; delete {data} and rerun")
        return seqs[0]
    if not data.is_dir():
        raise SlamInputError(f"{data}: not found in the unpacked archive; delete {root / src.target} and rerun")
    return data


def fetch(dataset: str, scene: str | None = None, to: str | Path = "data", *, mirror: str | None = None,
          sha256: str | None = None, frames: tuple[int, int] | None = None, keep_archive: bool = False,
          log=print) -> Path:
    """Download and unpack a dataset into ``to`` unless it is already there.

    Args:
        dataset, scene: see :func:`resolve`.
        to: the folder that receives the archive's folder (created).
        mirror: base URL replacing the publisher's (default ``$LRSLAM_DOWNLOAD_MIRROR``).
        sha256: expected sha256 of the archive, overriding :data:`KNOWN_CHECKSUMS`.
        frames: TUM only: ``(A, B)`` also writes pairs A..B-1 as ``<sequence>_A_<B-1>`` (see tum_window).
        keep_archive: keep the downloaded archive after unpacking (deleted by default: it doubles the space).
        log: receives one-line progress messages.

    Returns the folder to pass to ``lrslam run --data``. Raises SlamInputError (one line) on bad names, the
    network, a full disk or a checksum mismatch.
    """
    src = resolve(dataset, scene)
    if frames is not None and src.dataset != "tum":
        raise SlamInputError("--frames is for TUM sequences only")
    root = Path(to)
    target = root / src.target
    window = root / f"{src.member}_{frames[0]}_{frames[1] - 1}" if frames else None
    if window is not None and window.is_dir():
        log(f"already there: {window}")
        return window
    if target.is_dir():
        log(f"already there: {target}")
    else:
        arc = root / src.archive_name
        if not arc.is_file():  # a complete archive is never left unverified (archive.download)
            checksum = ("sha256", sha256) if sha256 else KNOWN_CHECKSUMS.get(src.archive_name)
            url = src.url(_mirror(mirror))
            log(f"downloading {url}")
            archive.download(url, arc, checksum=checksum)
        log(f"unpacking {arc.name} into {target}")
        target.parent.mkdir(parents=True, exist_ok=True)
        _unpack_into_place(src, arc, target)
        if not keep_archive:
            arc.unlink()
    if window is not None:
        from slam.data.tum_window import write_window

        log(f"writing pairs {frames[0]}..{frames[1] - 1} to {window}")
        return write_window(target, window, *frames)
    return _data_folder(src, root)


def _preset_exists(name: str) -> bool:
    """Whether ``name`` (e.g. ``tum/fr1_rpy``) is a preset under slam/configs."""
    from slam.config.load import CONFIG_DIR

    return (CONFIG_DIR / f"{name}.yaml").is_file()


def run_commands(dataset: str, scene: str | None, data: Path) -> list[str]:
    """The ``lrslam run`` command lines for a downloaded ``data`` folder: on the CPU (the realtime profile), then on
    a GPU (the paper profile), with the sequence's own preset where one exists (``tum/fr1_rpy``, ``replica/room0``;
    it holds a published box), else the preset ``--data`` alone detects."""
    src = resolve(dataset, scene)
    where = shlex.quote(str(data))
    if src.dataset == "replica":
        name = f"replica/{Path(src.data).name}"
    elif src.dataset == "tum":
        n, seq = tum_sequence(scene)
        name = f"tum/fr{n}_{seq}"
    else:
        name = src.dataset
    config = f"--config {name} " if name != src.dataset and _preset_exists(name) else ""
    return [f"lrslam run {config}--data {where}                # real time on the CPU",
            f"lrslam run {config}--data {where} --device cuda  # the published settings on a GPU"]
