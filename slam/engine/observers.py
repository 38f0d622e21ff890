"""Hooks a SLAM run calls as it goes: viewers, loggers, live plots, periodic checkpoints and stop conditions, all
things the loop itself knows nothing of.

An observer implements any of :meth:`Observer.on_start`, :meth:`Observer.on_frame`, :meth:`Observer.on_finish`
and :meth:`Observer.stop_requested` (the defaults do nothing). The loop (:meth:`slam.engine.system.SLAM.run`) calls
``on_frame`` after every frame, then asks every observer whether to stop; :func:`slam.run.runner.run_to_folder`
calls ``on_start`` before the first frame and ``on_finish`` once the outputs are written, then ``close``. Each hook
gets a read-only :class:`slam.engine.view.RunView` of the run, never the system.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class FrameRecord:
    """What one frame of the loop produced.

    Attributes:
        k: position in the processed sequence (0-based); ``frame``: the dataset index of that frame.
        color: ``[H, W, 3]`` RGB in [0, 1]; depth: ``[H, W]`` metres (0 invalid); on the run's device, or None
            for a frame that could not be read.
        pose: ``[4, 4]`` estimated camera-to-world (OpenCV camera, metres) after tracking and mapping.
        gt: ``[4, 4]`` ground-truth camera-to-world, or None.
        tracked, mapped: whether tracking / mapping ran on this frame.
        dt: wall time of the frame in seconds; ate_m: live ATE RMSE of the trajectory so far (metres, NaN
            before three frames or without ground truth). Both filled in by the loop after the step.
    """

    k: int
    frame: int
    color: torch.Tensor | None
    depth: torch.Tensor | None
    pose: torch.Tensor
    gt: torch.Tensor | None
    tracked: bool
    mapped: bool
    dt: float = float("nan")
    ate_m: float = float("nan")


class Observer:
    """Base class of run observers; override what you need."""

    def on_start(self, run) -> None:
        """Before the first frame (of this process: a resumed run has frames done); ``run``: a
        :class:`slam.engine.view.RunView`."""

    def on_frame(self, run, record: FrameRecord) -> None:
        """After every frame, in the order the observers were given."""

    def stop_requested(self) -> bool:
        """Asked after every frame's ``on_frame`` calls: True ends the loop there, as an interrupt does (the run
        writes its partial outputs and can be resumed)."""
        return False

    def on_finish(self, run, metrics: dict, mesh=None) -> None:
        """After the outputs are written: the run's metrics dict and its mesh (``trimesh.Trimesh``) or None."""

    def close(self) -> None:
        """Release files or connections; called once at the end, also when the run fails."""
