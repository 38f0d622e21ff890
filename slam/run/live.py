"""A SLAM run on a running camera into a folder (``lrslam live``): the loop takes the newest frame each time it is
free (:class:`slam.data.live.LiveFeed`), and the run ends when the camera does, or at Ctrl-C / SIGTERM, which stops
the camera: the frames taken are then finished, the mapper drained and every output written, as at the end of a
recorded sequence (trajectory, frames, metrics with the ``realtime`` block, mesh). A second signal stops at once.
A live run cannot be resumed (the stream is gone); the frames it received, recorded as a TUM folder, can be run
again offline with ``lrslam run --data FOLDER``.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Sequence

from slam.config import Config, save_config
from slam.engine.observers import Observer
from slam.engine.setup import resolve_device
from slam.engine.system import SLAM
from slam.errors import SlamInputError
from slam.run.outputs import trajectory_metrics, write_frames, write_mesh, write_metrics, write_trajectories

log = logging.getLogger("slam")

__all__ = ["live_to_folder"]


@contextlib.contextmanager
def _stop_camera_on_signal(feed):
    """SIGINT and SIGTERM stop the camera (the loop then ends as at the stream's end); a second one stops at once."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old, caught = {}, []

    def handler(signum, _frame):
        if caught:
            raise KeyboardInterrupt
        caught.append(signum)
        log.warning("%s received: stopping the camera, then finishing the frames taken and writing every output",
                    signal.Signals(signum).name)
        feed.stop()

    for sig in (signal.SIGINT, signal.SIGTERM):
        old[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def live_to_folder(cfg: Config, feed, out: str | Path, progress: bool = True, mesh: bool = True,
                   observers: Sequence[Observer] = ()) -> dict:
    """Run SLAM on ``feed`` (a :class:`slam.data.live.LiveFeed`, already receiving) until it ends and write every
    output to ``out``; returns the metrics (also ``metrics.json``). ``cfg.data.realtime`` should be true (the
    ``realtime`` block of the metrics). The feed is closed on return, whatever happened."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_config(cfg, out / "config.yaml")
    system = None
    abort = False
    try:
        t0 = time.perf_counter()
        if feed.wait_beyond(0) == 0:
            raise SlamInputError(f"the camera delivered no frame{': ' + feed.error if feed.error else ''}")
        system = SLAM(cfg, feed, resolve_device(cfg.device))
        for obs in observers:
            obs.on_start(system.view())
        with _stop_camera_on_signal(feed):
            system.run(progress=progress, observers=observers)
        loop_s = time.perf_counter() - t0
        run = system.view()
        write_trajectories(run, out)
        write_frames(run, out)
        metrics = trajectory_metrics(run, out)
        metrics.update(loop_s=loop_s, frames_received=len(feed), camera_error=feed.error or None,
                       mapping_wait_s=system.mapper.wait_s, mapping_s=system.mapper.map_s,
                       mapping_calls=system.mapper.calls, mapping_declined=system.mapper.declined,
                       preload_s=system.preload_s)
        m = write_mesh(run, out, metrics) if mesh else None
        write_metrics(metrics, out)
        for obs in observers:
            obs.on_finish(run, metrics, m)
    except BaseException as exc:
        abort = not isinstance(exc, Exception)
        raise
    finally:
        for obs in observers:
            obs.close()
        feed.close()
        if system is not None:
            system.close(abort=abort)
    return metrics
