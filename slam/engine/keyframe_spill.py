"""Keyframe images on disk: :class:`SpillFile` holds the images of keyframes that left the store's in-memory
window (``mapping.keyframes_in_memory``) in one unlinked temporary file, and reads them back when a mapping window
selects them. The bytes are written as stored (float32, or the compact 8-bit / float16 form), so what comes back
is bit-identical to what went out and a run's results do not depend on where its keyframes live
(docs/robustness.md, "Memory on long runs")."""

from __future__ import annotations

import os
import tempfile
import threading
from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["SpillFile", "SpilledImages"]


@dataclass(frozen=True)
class SpilledImages:
    """Where one keyframe's images lie in a :class:`SpillFile`: its ``slot`` and the colour's and depth's shapes
    and dtypes (``color [H, W, 3]``, ``depth [H, W]``)."""

    file: "SpillFile"
    slot: int
    color_shape: tuple[int, ...]
    color_dtype: torch.dtype
    depth_shape: tuple[int, ...]
    depth_dtype: torch.dtype

    def read(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(color, depth)`` as they were written (same shapes, dtypes and bits)."""
        return self.file.read(self)


def _nbytes(shape: tuple[int, ...], dtype: torch.dtype) -> int:
    return int(np.prod(shape)) * torch.empty((), dtype=dtype).element_size()


class SpillFile:
    """Fixed-size slots of raw image bytes in a temporary file that the operating system deletes when it is closed
    or the process ends (``tempfile.TemporaryFile``), so a crash leaves nothing behind.

    Args:
        directory: where to create the file (``None`` or ``""``: the system's temporary directory).

    Thread-safe: the mapping thread writes while the tracker's relocalisation may read.
    """

    def __init__(self, directory: str | None = None):
        self.directory = os.path.expanduser(directory) if directory else None
        self._fh = tempfile.TemporaryFile(dir=self.directory, prefix="lrslam-keyframes-")
        self._lock = threading.Lock()
        self._slot_bytes = 0
        self._slots = 0
        self._free: list[int] = []
        self.in_use = 0

    @property
    def nbytes(self) -> int:
        """Bytes of images held in the file now (freed slots not counted)."""
        return self.in_use * self._slot_bytes

    def write(self, color: torch.Tensor, depth: torch.Tensor) -> SpilledImages:
        """Write one keyframe's ``color`` and ``depth`` (CPU tensors) to a free slot.

        Raises:
            OSError: the file cannot be written (a full disk, a removed directory); nothing was changed.
        """
        c = color.detach().cpu().contiguous().numpy()
        d = depth.detach().cpu().contiguous().numpy()
        size = c.nbytes + d.nbytes
        with self._lock:
            if self._slot_bytes and size != self._slot_bytes:
                raise ValueError(f"keyframe images of {size} bytes in a spill file of {self._slot_bytes}-byte slots")
            self._slot_bytes = size
            slot = self._free.pop() if self._free else self._slots
            try:
                self._fh.seek(slot * size)
                self._fh.write(c.data)  # the arrays' own buffers: no copy
                self._fh.write(d.data)
                self._fh.flush()
            except OSError:
                if slot != self._slots:
                    self._free.append(slot)
                raise
            self._slots = max(self._slots, slot + 1)
            self.in_use += 1
        return SpilledImages(self, slot, tuple(color.shape), color.dtype, tuple(depth.shape), depth.dtype)

    def read(self, where: SpilledImages) -> tuple[torch.Tensor, torch.Tensor]:
        """The images written as ``where``."""
        bufs = [bytearray(_nbytes(where.color_shape, where.color_dtype)),
                bytearray(_nbytes(where.depth_shape, where.depth_dtype))]
        with self._lock:
            self._fh.seek(where.slot * self._slot_bytes)
            got = [self._fh.readinto(b) for b in bufs]
        if got != [len(b) for b in bufs]:
            raise OSError(f"keyframe spill file: slot {where.slot} is short ({sum(got)} of {self._slot_bytes} bytes)")
        # separate buffers: a float16 depth after an odd-sized 8-bit colour would be misaligned in one buffer
        color = torch.frombuffer(bufs[0], dtype=where.color_dtype).reshape(where.color_shape)
        depth = torch.frombuffer(bufs[1], dtype=where.depth_dtype).reshape(where.depth_shape)
        return color, depth

    def free(self, where: SpilledImages) -> None:
        """Give ``where``'s slot back (its keyframe was dropped)."""
        with self._lock:
            self._free.append(where.slot)
            self.in_use -= 1

    def close(self) -> None:
        """Close (and so delete) the file."""
        self._fh.close()
