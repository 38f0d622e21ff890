"""Frames delivered the way a live camera delivers them (``data.realtime: true``, ``lrslam run --realtime``).

A recorded sequence is replayed at its recorded rate: selected frame ``p`` arrives ``t[p] - t[0]`` seconds after
the clock starts (its timestamps; 30 Hz per dataset frame without them). After each frame the loop takes the
newest frame that has arrived, and drops the ones that arrived while it was busy and were never taken: a camera
does not wait. When the loop is faster than the camera it waits for the next frame. Which frames are processed
then depends on how fast the machine is, so a real-time run repeats only on the same machine under the same load;
the frames it dropped are kept in its checkpoint, so ``--resume`` goes on from the same ones (the clock restarts at
the resumed frame). The latency of a frame is from its arrival to its pose; reading its files is part of it.

A live camera (:mod:`slam.data.live`) is taken the same way, its frames added to the run as they arrive
(:func:`take_live`).
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np

__all__ = ["Replay", "arrival_times", "latency_summary", "note_latency", "pass_over", "take_live", "take_next",
           "take_replayed"]


def arrival_times(indices: Sequence[int], timestamps: Sequence[float] | None) -> np.ndarray:
    """``[N]`` seconds from the first selected frame to each one: their timestamps, or 30 Hz per dataset frame
    (the same rule as the tracker's motion checks) where the data have none."""
    if timestamps is None:
        return (np.asarray(indices, dtype=np.float64) - indices[0]) / 30.0
    t = np.asarray([float(timestamps[i]) for i in indices], dtype=np.float64)
    return t - t[0]


class Replay:
    """The arrival clock of the selected frames.

    Args:
        times: ``[N]`` seconds from the first selected frame to each (non-decreasing; :func:`arrival_times`).
        now, sleep: the clock (seconds) and how to wait; tests pass a simulated one.
    """

    def __init__(self, times: np.ndarray, now: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep):
        self.times = np.asarray(times, dtype=np.float64)
        self.now, self.sleep = now, sleep
        self.t0 = None

    def start(self, p: int) -> None:
        """Start the clock so that selected frame ``p`` (the first to process) arrives now."""
        self.t0 = self.now() - self.times[p]

    def arrival(self, p: int) -> float:
        """When selected frame ``p`` arrives, on the clock ``now``."""
        return float(self.t0 + self.times[p])

    def take(self, p: int) -> int:
        """The selected frame to process when ``p`` is the oldest not yet taken or dropped: waits until ``p`` has
        arrived, then returns the newest one that has (``>= p``; those between are dropped)."""
        if self.t0 is None:
            self.start(p)
        wait = self.arrival(p) - self.now()
        if wait > 0:
            self.sleep(wait)
        newest = int(np.searchsorted(self.times, self.now() - self.t0, side="right")) - 1
        return max(newest, p)


def latency_summary(latency: Sequence[float], dropped: int) -> dict:
    """The ``realtime`` block of ``metrics.json``: frames processed and dropped, the latency from a frame's
    arrival to its pose (median, 95th percentile, largest; seconds)."""
    lat = np.asarray(latency, dtype=np.float64)
    stats = {} if not lat.size else {"latency_median_s": round(float(np.median(lat)), 4),
                                     "latency_p95_s": round(float(np.percentile(lat, 95)), 4),
                                     "latency_max_s": round(float(lat.max()), 4)}
    return {"frames_processed": int(lat.size), "frames_dropped": int(dropped), **stats}


def pass_over(system, positions: list[int]) -> None:
    """Frames at these positions of ``system`` (a :class:`slam.engine.system.SLAM`; not processed yet) arrived
    while the loop was busy and are never taken: they leave its frames to process (``indices``, the ground truth,
    the timestamps, the frame reader's list), and ``state.dropped`` lists them."""
    if not positions:
        return
    gone = set(positions)
    keep = [k for k in range(len(system.indices)) if k not in gone]
    system.state.dropped.extend(int(system.indices[k]) for k in sorted(gone))
    system.indices[:] = [system.indices[k] for k in keep]
    system.frames.indices[:] = system.indices
    if system.gt is not None:
        system.gt = system.gt[keep]
    if system.timestamps is not None:
        system.timestamps = system.timestamps[keep]


def take_replayed(system, k: int) -> float:
    """A replay (``system.replay``): wait for the frame at position ``k`` to arrive and pass over the frames that
    arrived before the newest one that has, which becomes frame ``k``; returns its arrival time."""
    p = k + len(system.state.dropped)  # its position in the selection (only frames before it were passed over)
    q = system.replay.take(p)
    pass_over(system, list(range(k, k + q - p)))
    return system.replay.arrival(q)


def take_live(system, k: int) -> float | None:
    """A live camera (``system.ds``, :class:`slam.data.live.LiveFeed`): wait for a frame newer than those known
    unless one is waiting, add the new ones to the frames to process and pass over all but the newest, which
    becomes frame ``k``; returns its arrival time (``time.perf_counter``), or None once the stream has ended with
    nothing left to take."""
    ds = system.ds
    n = ds.wait_beyond(len(system.selection)) if k >= len(system.indices) else len(ds)
    new = list(range(len(system.selection), n))
    if new:
        system.selection += new
        system.indices += new
        system.frames.indices += new
        system.timestamps = np.concatenate((system.timestamps, [float(ds.timestamps[i]) for i in new]))
    if k >= len(system.indices):
        return None
    pass_over(system, list(range(k, len(system.indices) - 1)))
    return ds.arrived[system.indices[k]]


def take_next(system, k: int) -> tuple[bool, float | None]:
    """The frame at position ``k`` of ``system`` (a :class:`slam.engine.system.SLAM`) to process next: ``(whether
    there is one, its arrival time or None)``. A live camera's (:func:`take_live`) or a replay's
    (:func:`take_replayed`) frame arrives; a recorded run's frames are all there (no arrival time)."""
    if system.live:
        arrived = take_live(system, k)
        return arrived is not None, arrived
    if k >= len(system.indices):
        return False, None
    return True, take_replayed(system, k) if system.replay is not None else None


def note_latency(system, arrived: float | None) -> None:
    """Record the latency (seconds) of the frame just given its pose, which arrived at ``arrived`` (None: a
    recorded run, no latency) on the replay's clock or a live camera's (``time.perf_counter``)."""
    if arrived is not None:
        now = system.replay.now() if system.replay is not None else time.perf_counter()
        system.state.latency.append(float(now - arrived))  # a plain float: checkpoints
