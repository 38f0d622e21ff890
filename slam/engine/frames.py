"""The frames a run reads, ahead of time and without aborting on a bad one.

:class:`FrameSource` reads the selected frames of a dataset in order, the next ``ahead`` in advance: reading,
decoding, undistorting and resizing them and putting them on the run's device. ``data.prefetch_in: thread`` does that
on a background thread while the loop works on the current frame (image decoding and torch's resampling release the
GIL, so this uses the second core); ``waits`` does it on the loop's own thread while the loop waits for the mapper
(:meth:`FrameSource.read_while`), so no thread competes with the tracker for the interpreter and the cores (ours:
7-9 % of the frame time at the realtime profile, docs/slam.md, "Frames read in the tracker's waits"). A frame that
cannot be read (missing, truncated or corrupt file, wrong image size) comes back as a :class:`LoadedFrame` with
``error`` set instead of raising, so the loop can skip it like a frame without depth and keep the run.

This module is the one place a run reads its dataset's frames: the loop through :class:`FrameSource`, the set-up
through :func:`first_readable`, and the automatic box, meshing and the reconstruction metrics through
:func:`readable_depth`.
"""

from __future__ import annotations

import concurrent.futures
import logging
from dataclasses import dataclass
from typing import Callable

import torch

from slam.errors import SlamInputError

log = logging.getLogger("slam")


@dataclass
class LoadedFrame:
    """One frame ready for the loop.

    Attributes:
        k: position in the processed sequence; ``index``: the dataset index.
        color: ``[H, W, 3]`` float32 RGB in [0, 1] on the run's device, or None for a bad frame.
        depth: ``[H, W]`` float32 metres on the device (0 invalid; non-finite readings set to 0), or None.
        error: why the frame could not be read (names the file), None for a good frame.
    """

    k: int
    index: int
    color: torch.Tensor | None
    depth: torch.Tensor | None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def has_depth(self) -> bool:
        return self.ok and bool((self.depth > 0).any())


def read_frame(dataset, k: int, index: int, shape: tuple[int, int], device: torch.device) -> LoadedFrame:
    """Read frame ``index`` of ``dataset`` as a :class:`LoadedFrame` of working size ``shape`` ``(H, W)``."""
    try:
        frame = dataset[index]
        color = torch.as_tensor(frame.color, dtype=torch.float32)
        depth = torch.as_tensor(frame.depth, dtype=torch.float32)
    except (SlamInputError, OSError, ValueError) as exc:
        return LoadedFrame(k, index, None, None, error=str(exc))
    if tuple(depth.shape) != tuple(shape) or tuple(color.shape) != (*shape, 3):
        return LoadedFrame(k, index, None, None, error=(
            f"frame {index}: images are {tuple(color.shape[:2])} (colour) / {tuple(depth.shape)} (depth) after "
            f"loading, expected {tuple(shape)} like the first frame"))
    depth = torch.where(torch.isfinite(depth), depth, torch.zeros_like(depth))
    if device.type == "cuda":
        color, depth = color.pin_memory(), depth.pin_memory()
    return LoadedFrame(k, index, color.to(device, non_blocking=True), depth.to(device, non_blocking=True))


def first_readable(dataset, indices: list[int], tries: int):
    """``(position, frame)``: the first of the first ``tries`` selected frames that loads, as the dataset gives it
    (its intrinsics and depth set a run up); the bad ones before it are logged.

    Raises:
        SlamInputError: none of them loads (names the last error)."""
    last_exc = None
    for k, i in enumerate(indices[: max(1, tries)]):
        try:
            return k, dataset[i]
        except (SlamInputError, OSError, ValueError) as exc:
            last_exc = exc
            log.warning("frame %d: unreadable (%s)", i, exc)
    raise SlamInputError(f"no readable frame at the start of the sequence: {last_exc}")


def readable_depth(dataset, index: int):
    """The depth ``[H, W]`` (metres) of dataset frame ``index``, or None when the frame cannot be read: outputs
    written after a run (culling, meshing) must survive every frame the run itself survived."""
    try:
        return dataset[index].depth
    except (SlamInputError, OSError, ValueError):
        return None


class FrameSource:
    """Frames ``indices[k]`` of ``dataset`` in increasing ``k``, read ``ahead`` frames in advance.

    Args:
        dataset: a ``slam.data`` dataset.
        indices: dataset index of each processed frame.
        shape: ``(H, W)`` every frame must have after loading.
        device: where the tensors go.
        ahead: frames read in advance (0: read on demand, on the caller's thread).
        in_waits: read them in the loop's waits for the mapper (:meth:`read_while`) instead of on a background
            thread; a frame not read by then is read on demand.
    """

    def __init__(self, dataset, indices: list[int], shape: tuple[int, int], device: torch.device, ahead: int = 2,
                 in_waits: bool = False):
        self.dataset = dataset
        self.indices = list(indices)
        self.shape = tuple(shape)
        self.device = torch.device(device)
        self.ahead = int(ahead)
        self.in_waits = bool(in_waits)
        threaded = ahead > 0 and not self.in_waits
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="lrslam-read") if threaded else None
        self._pending: dict[int, concurrent.futures.Future] = {}
        self._read: dict[int, LoadedFrame] = {}  # read in the loop's waits (in_waits), not yet taken

    def _submit(self, k: int) -> None:
        if k < len(self.indices) and k not in self._pending:
            self._pending[k] = self._pool.submit(read_frame, self.dataset, k, self.indices[k], self.shape, self.device)

    def _read_now(self, k: int) -> LoadedFrame:
        return read_frame(self.dataset, k, self.indices[k], self.shape, self.device)

    def get(self, k: int) -> LoadedFrame:
        """Frame ``k`` (reads ahead up to ``k + ahead``; frames before ``k`` still pending are dropped)."""
        if self._pool is None:
            for old in [j for j in self._read if j < k]:
                del self._read[old]
            return self._read.pop(k) if k in self._read else self._read_now(k)
        for old in [j for j in self._pending if j < k]:
            self._pending.pop(old).cancel()
        for j in range(k, k + self.ahead + 1):
            self._submit(j)
        return self._pending.pop(k).result()

    def read_while(self, k: int, busy: Callable[[], bool]) -> int:
        """With ``in_waits``: read frames ``k ... k + ahead`` not read yet, one at a time, while ``busy()`` (the
        mapper call the loop waits for runs); returns how many were read. Without, a no-op (the thread reads)."""
        if not self.in_waits:
            return 0
        n = 0
        for j in range(k, min(k + self.ahead + 1, len(self.indices))):
            if j in self._read:
                continue
            if not busy():
                break
            self._read[j] = self._read_now(j)
            n += 1
        return n

    def close(self) -> None:
        if self._pool is not None:
            for fut in self._pending.values():
                fut.cancel()
            self._pending.clear()
            self._pool.shutdown(wait=True)
            self._pool = None
        self._read.clear()
