"""Frames delivered the way a live camera delivers them (``data.realtime: true``, ``lrslam run --realtime``).

A recorded sequence is replayed at its recorded rate: selected frame ``p`` arrives ``t[p] - t[0]`` seconds after
the clock starts (its timestamps; 30 Hz per dataset frame without them). After each frame the loop takes the
newest frame that has arrived, and drops the ones that arrived while it was busy and were never taken: a camera
does not wait. When the loop is faster than the camera it waits for the next frame. Which frames are processed
then depends on how fast the machine is, so a real-time run repeats only on the same machine under the same load;
the frames it dropped are kept in its checkpoint, so ``--resume`` goes on from the same ones (the clock restarts at
the resumed frame). The latency of a frame is from its arrival to its pose; reading its files is part of it.
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np

__all__ = ["Replay", "arrival_times", "latency_summary"]


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
