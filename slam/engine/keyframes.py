"""Keyframe store and ESLAM's overlap-based mapping window (docs/slam.md, "The pipeline (as implemented)", Mapping)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import torch

from slam.core.camera import pixel_directions
from slam.core.pose import pose_distance, pose_to_matrix
from slam.engine.keyframe_spill import SpillFile, SpilledImages

log = logging.getLogger(__name__)


def _float_rgb(color: torch.Tensor) -> torch.Tensor:
    """Stored colour (uint8, or float in [0, 1]) -> float32 in [0, 1]."""
    return color.float() / 255.0 if color.dtype == torch.uint8 else color.float()


@dataclass
class Keyframe:
    """One stored keyframe: ``color [H, W, 3]`` and ``depth [H, W]`` (metres) as stored, its estimated pose as
    ``[7]`` (q, t) camera-to-world (refined by BA). Read the images with :meth:`rgb` / :meth:`metres`, which
    return float32 whatever the storage, and wherever the images are: in memory, or (``color`` and ``depth``
    None) in the store's spill file at ``spilled``."""

    index: int
    color: torch.Tensor | None
    depth: torch.Tensor | None
    pose: torch.Tensor
    spilled: SpilledImages | None = None

    def images(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(color, depth)`` as stored (read back from disk when spilled)."""
        color, depth = self.color, self.depth  # one read of each: the mapping thread may spill it meanwhile
        if color is None or depth is None:
            return self.spilled.read()
        return color, depth

    def float_images(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(rgb [H, W, 3] in [0, 1], depth [H, W] in metres)``, float32, from one read of a spilled keyframe."""
        color, depth = self.images()
        return _float_rgb(color), depth.float()

    def rgb(self) -> torch.Tensor:
        """``[H, W, 3]`` float32 RGB in [0, 1]."""
        return _float_rgb(self.images()[0])

    def metres(self) -> torch.Tensor:
        """``[H, W]`` float32 depth in metres."""
        return self.images()[1].float()

    @property
    def nbytes(self) -> int:
        """Bytes of images held in memory (0 once spilled)."""
        color, depth = self.color, self.depth
        if color is None or depth is None:
            return 0
        return color.numel() * color.element_size() + depth.numel() * depth.element_size()


def bytes_per_keyframe(height: int, width: int, storage: str = "float32") -> int:
    """Image bytes one keyframe holds: float32 colour and depth (16 bytes a pixel), or ``compact``: 8-bit colour
    and float16 depth (5 bytes a pixel)."""
    return height * width * (16 if storage == "float32" else 5)


@dataclass
class KeyframeStore:
    """Ordered list of keyframes (by frame index).

    Args:
        storage: ``float32`` keeps the images as loaded; ``compact`` stores colour as 8-bit (an error of at most
            half a grey level) and depth as float16 (relative error <= 2^-11, 2 mm at 4 m): 3.2x less memory.
        max_keyframes: 0 keeps every keyframe; otherwise, past this count, the most redundant one is dropped (the
            keyframe, other than the first and the last two, whose pose is closest to its predecessor's:
            translation in metres plus 0.5 m per radian of rotation), so memory stays bounded on long sequences.
        in_memory: 0 keeps every keyframe's images in memory; otherwise only the newest ``in_memory`` keyframes'
            images stay, older ones move to a temporary file in ``spill_dir`` (``""``: the system's temporary
            directory) and are read back, bit-identical, when selected. Where the file cannot be written (a full
            disk), the images stay in memory, the reason is logged and kept in ``spill_error``, and the run goes on.
    """

    frames: list[Keyframe] = field(default_factory=list)
    storage: str = "float32"
    max_keyframes: int = 0
    dropped: int = 0
    in_memory: int = 0
    spill_dir: str = ""
    spill_error: str = ""
    spill: SpillFile | None = field(default=None, repr=False)

    @classmethod
    def for_mapping(cls, mapping) -> "KeyframeStore":
        """An empty store as a :class:`slam.config.MappingConfig` sets it up (``keyframe_storage``,
        ``max_keyframes``, ``keyframes_in_memory``, ``keyframe_spill_dir``)."""
        return cls(storage=mapping.keyframe_storage, max_keyframes=mapping.max_keyframes,
                   in_memory=mapping.keyframes_in_memory, spill_dir=mapping.keyframe_spill_dir)

    def __len__(self) -> int:
        return len(self.frames)

    def add(self, kf: Keyframe, drop: bool = True) -> None:
        """Store ``kf`` (converted to ``storage``); past ``max_keyframes`` drop the most redundant keyframe, unless
        ``drop`` is False (a mirror that takes its drops from another store: :meth:`follow`)."""
        if self.storage == "compact":
            kf = Keyframe(kf.index, (kf.rgb() * 255.0).round().clamp(0, 255).to(torch.uint8),
                          kf.metres().to(torch.float16), kf.pose)
        self.frames.append(kf)
        if drop and self.max_keyframes and len(self.frames) > self.max_keyframes:
            self._drop(self.frames[self._most_redundant()])
        if self.in_memory and not self.spill_error:
            resident = [f for f in self.frames if f.color is not None]
            for old in resident[: max(len(resident) - self.in_memory, 0)]:
                if not self._spill(old):
                    break

    def _drop(self, gone: Keyframe) -> None:
        self.frames.remove(gone)
        if gone.spilled is not None:
            gone.spilled.file.free(gone.spilled)
        self.dropped += 1

    def follow(self, indices: list[int], poses: torch.Tensor) -> None:
        """Become the mirror of another store that holds the keyframes of frame positions ``indices`` (in order)
        with poses ``[K, 7]``: drop the keyframes it dropped and take its (BA-refined) poses. The mapper process's
        store decides which keyframe goes by its own poses, which the mirror has not seen yet, so the mirror must
        not decide for itself.

        Raises:
            RuntimeError: ``indices`` are not this store's keyframes less some dropped ones, or do not match
                ``poses`` (the two stores no longer hold the same frames)."""
        keep = set(indices)
        for gone in [kf for kf in self.frames if kf.index not in keep]:
            self._drop(gone)
        held = [kf.index for kf in self.frames]
        if held != list(indices) or len(poses) != len(held):
            raise RuntimeError(f"the keyframe mirror holds frames {held}, the mapping process {list(indices)} "
                               f"({len(poses)} poses)")
        for kf, pose in zip(self.frames, poses):
            kf.pose = pose.clone()

    def _spill(self, kf: Keyframe) -> bool:
        try:
            if self.spill is None:
                self.spill = SpillFile(self.spill_dir)
            kf.spilled = self.spill.write(kf.color, kf.depth)
        except OSError as exc:
            self.spill_error = f"keyframe images stay in memory: cannot write to {self.spill_dir or 'the temp dir'}: {exc}"
            log.warning("%s (mapping.keyframe_spill_dir / mapping.keyframes_in_memory)", self.spill_error)
            return False
        kf.color = kf.depth = None  # after ``spilled`` is set: a reader on another thread sees one or the other
        return True

    @property
    def spilled_bytes(self) -> int:
        """Bytes of keyframe images on disk."""
        return 0 if self.spill is None else self.spill.nbytes

    def close(self) -> None:
        """Delete the spill file (the spilled keyframes become unreadable)."""
        if self.spill is not None:
            self.spill.close()

    def state_dict(self) -> dict:
        """``{"keyframes": [{"k", "pose"}], "keyframes_dropped"}``: positions and poses of the keyframes kept and
        how many were dropped. The images are not stored: they are read again from the data on load."""
        return {"keyframes": [{"k": kf.index, "pose": kf.pose.clone()} for kf in self.frames],
                "keyframes_dropped": self.dropped}

    def load_state_dict(self, state: dict, read: Callable[[int], tuple[torch.Tensor, torch.Tensor]]) -> None:
        """Replace the keyframes with a :meth:`state_dict`'s; ``read(k)`` gives frame position ``k``'s colour
        ``[H, W, 3]`` and depth ``[H, W]`` as the loop loaded them."""
        self.frames.clear()
        self.close()
        self.spill = None
        self.dropped = int(state.get("keyframes_dropped", 0))
        for kf in state["keyframes"]:
            color, depth = read(kf["k"])
            self.add(Keyframe(kf["k"], color, depth, kf["pose"].clone()), drop=False)  # the ones kept: no dropping

    def _most_redundant(self) -> int:
        T = keyframe_matrices(self.poses())
        best, best_d = 1, float("inf")
        for i in range(1, len(self.frames) - 2):
            d = pose_distance(T[i - 1], T[i])
            if d < best_d:
                best, best_d = i, d
        return best

    @property
    def nbytes(self) -> int:
        """Bytes of the stored images held in memory (see :attr:`spilled_bytes` for those on disk)."""
        return sum(kf.nbytes for kf in self.frames)

    def poses(self) -> torch.Tensor:
        """``[K, 7]`` current estimated poses."""
        return torch.stack([k.pose for k in self.frames]) if self.frames else torch.zeros(0, 7)


def overlapping_keyframes(
    depth: torch.Tensor,
    c2w: torch.Tensor,
    keyframe_c2w: torch.Tensor,
    fx: float, fy: float, cx: float, cy: float, height: int, width: int,
    n_pixels: int = 50,
    n_samples: int = 8,
    margin: int = 20,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Which keyframes see points of the current frame (ESLAM 'overlap' selection, steps 1-3).

    Casts ``n_pixels`` random valid-depth pixels, puts ``n_samples`` evenly spaced points on each in
    ``[0.8 D, D + 0.5]``, projects them into every keyframe and reports the keyframes that have at least one
    point in front of the camera and inside the image with a ``margin`` px border.

    Args:
        depth: ``[H, W]`` current depth (metres, 0 invalid).
        c2w: ``[4, 4]`` current camera-to-world.
        keyframe_c2w: ``[K, 4, 4]`` keyframe camera-to-world (OpenCV).

    Returns:
        ``[K]`` bool mask.
    """
    K = keyframe_c2w.shape[0]
    valid = torch.nonzero(depth > 0)
    if K == 0 or valid.shape[0] == 0:
        return torch.zeros(K, dtype=torch.bool)
    pick = torch.randint(0, valid.shape[0], (n_pixels,), generator=generator)
    vu = valid[pick]
    v = vu[:, 0].to(depth.dtype)
    u = vu[:, 1].to(depth.dtype)
    D = depth[vu[:, 0], vu[:, 1]]
    t = torch.linspace(0.0, 1.0, n_samples, dtype=depth.dtype)
    z = 0.8 * D[:, None] + (D[:, None] + 0.5 - 0.8 * D[:, None]) * t  # [P, S]
    dirs = pixel_directions(u, v, fx, fy, cx, cy)
    pts_cam = dirs[:, None, :] * z[..., None]  # [P, S, 3]
    pts = pts_cam.reshape(-1, 3) @ c2w[:3, :3].T + c2w[:3, 3]
    w2c = torch.linalg.inv(keyframe_c2w)  # [K, 4, 4]
    pc = torch.einsum("kij,pj->kpi", w2c[:, :3, :3], pts) + w2c[:, None, :3, 3]
    zc = pc[..., 2]
    zs = torch.where(zc.abs() < 1e-5, torch.full_like(zc, 1e-5), zc)
    uu = fx * pc[..., 0] / zs + cx
    vv = fy * pc[..., 1] / zs + cy
    inside = (uu > margin) & (uu < width - margin) & (vv > margin) & (vv < height - margin) & (zc > 0)
    return inside.any(-1)


def select_window(
    n_keyframes: int,
    overlap: torch.Tensor,
    window_size: int = 20,
    generator: torch.Generator | None = None,
) -> list[int]:
    """ESLAM's window (steps 4-5): up to ``window_size - 1`` random overlapping keyframes among all but the
    last two, plus the last two keyframes. The caller adds the current frame.

    Args:
        n_keyframes: number of stored keyframes.
        overlap: ``[n_keyframes]`` bool (only entries before the last two are used).
        window_size: ESLAM's ``mapping_window_size`` W.

    Returns:
        Sorted keyframe positions (indices into the store).
    """
    older = max(n_keyframes - 2, 0)
    cand = [i for i in range(older) if bool(overlap[i])]
    if len(cand) > window_size - 1:
        perm = torch.randperm(len(cand), generator=generator)[: window_size - 1]
        cand = [cand[int(i)] for i in perm]
    chosen = set(cand) | set(range(older, n_keyframes))
    return sorted(chosen)


def keyframe_matrices(poses: torch.Tensor) -> torch.Tensor:
    """``[K, 7]`` -> ``[K, 4, 4]`` (no gradient)."""
    with torch.no_grad():
        return pose_to_matrix(poses)
