"""A typed, read-only view of a run: what outputs, checkpoints, the mesher and observers read of it.

:meth:`slam.engine.system.SLAM.view` builds one. It holds the run's fixed facts (config, frames, intrinsics, ground
truth, boxes), the per-frame state so far, the map the tracker reads, and two functions: :meth:`RunView.keyframes`
(waits until the mapper is idle, then copies the keyframes' positions, poses and depths) and
:meth:`RunView.read_depth` (a processed frame's depth, read again from the data, None when unreadable). Nothing in
it lets a reader change the run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from slam.core.pose import pose_to_matrix
from slam.engine.state import RunState


@dataclass(frozen=True)
class KeyframeSnapshot:
    """The keyframes at one moment: ``positions`` in the processed sequence, ``poses`` ``[K, 4, 4]`` camera-to-world
    (BA-refined), ``depths`` ``[H, W]`` metres each (float32, the stored tensors: do not modify)."""

    positions: tuple[int, ...]
    poses: np.ndarray
    depths: tuple[torch.Tensor, ...]


@dataclass(frozen=True)
class RunView:
    """Read-only view of a run.

    Attributes:
        cfg: the run's config; device: where the map lives; intrinsics: of the working image.
        indices: dataset index of each selected frame (processed or not yet).
        timestamps: ``[len(indices)]`` seconds of the selected frames, or None (the dataset has none).
        gt: ``[len(indices), 4, 4]`` ground-truth camera-to-world, or None.
        c2w0: ``[4, 4]`` the first frame's pose (see ``c2w0_source``).
        bound, mc_bound: ``[3, 2]`` scene and marching-cubes boxes (metres, lists); aabb: ``[3, 2]`` the fields' box.
        scene: the map the tracker reads (after the last frame: the final map).
        state: the loop's :class:`slam.engine.state.RunState` (read it, never write it).
        gt_mesh_path: the dataset's ground-truth mesh, or None.
        keyframe_count: keyframes when the view was taken (read without waiting for the mapper).
    """

    cfg: object
    device: torch.device
    intrinsics: object
    indices: tuple[int, ...]
    timestamps: np.ndarray | None
    gt: torch.Tensor | None
    c2w0: torch.Tensor
    c2w0_source: str
    bound: list
    mc_bound: list
    aabb: torch.Tensor
    scene: torch.nn.Module
    state: RunState
    gt_mesh_path: Path | None
    keyframe_count: int
    _keyframes: Callable[[], KeyframeSnapshot]
    _read_depth: Callable[[int], np.ndarray | None]

    @property
    def done(self) -> int:
        """Frames processed so far."""
        return len(self.state.est)

    def poses(self) -> np.ndarray:
        """``[done, 4, 4]`` estimated camera-to-world of the processed frames: the trajectory a run writes, corrected
        by the pose graph once a run with ``loops.enabled`` has ended (:mod:`slam.loop`), else the tracker's."""
        if self._corrected():
            return np.asarray(self.state.corrected)
        return self.odometry_poses()

    def map_poses(self) -> np.ndarray:
        """``[done, 4, 4]`` camera-to-world the map is in: the corrected poses once the map was re-fitted on them
        (``loops.refine_iters``, :mod:`slam.engine.refine`), else the tracker's (:meth:`odometry_poses`)."""
        if self.state.refined is not None and self._corrected():
            return np.asarray(self.state.corrected)
        return self.odometry_poses()

    def odometry_poses(self) -> np.ndarray:
        """``[done, 4, 4]`` the tracker's camera-to-world (with BA's refinements), before any loop correction."""
        if not self.state.est:
            return np.zeros((0, 4, 4))
        return pose_to_matrix(torch.stack(self.state.est)).numpy()

    def _corrected(self) -> bool:
        return self.state.corrected is not None and len(self.state.corrected) == self.done

    def frame_timestamps(self) -> np.ndarray:
        """``[done]`` seconds of the processed frames (the dataset's timestamps, else 30 Hz from 0)."""
        if self.timestamps is None:
            return np.arange(self.done) / 30.0
        return np.asarray(self.timestamps[: self.done], dtype=np.float64)

    def keyframes(self) -> KeyframeSnapshot:
        """The keyframes now (waits for a mapping call in progress: they are the mapper's while it runs)."""
        return self._keyframes()

    def read_depth(self, k: int) -> np.ndarray | None:
        """``[H, W]`` depth in metres of processed frame ``k`` as the dataset gives it, or None if unreadable."""
        return self._read_depth(k)


def view_of(s) -> RunView:
    """The :class:`RunView` of ``s`` (a :class:`slam.engine.system.SLAM`)."""
    from slam.engine.frames import readable_depth

    def keyframes() -> KeyframeSnapshot:
        frames = s.keyframes_when_idle()
        poses = pose_to_matrix(s.keyframes.poses()).numpy() if frames else np.zeros((0, 4, 4))
        return KeyframeSnapshot(tuple(kf.index for kf in frames), poses, tuple(kf.metres() for kf in frames))

    return RunView(cfg=s.cfg, device=s.device, intrinsics=s.intr, indices=tuple(s.indices), timestamps=s.timestamps,
                   gt=s.gt, c2w0=s.c2w0, c2w0_source=s.c2w0_source, bound=s.bound, mc_bound=s.mc_bound, aabb=s.aabb,
                   scene=s.mapper.track_scene, state=s.state, gt_mesh_path=getattr(s.ds, "gt_mesh_path", None),
                   keyframe_count=len(s.keyframes), _keyframes=keyframes,
                   _read_depth=lambda k: readable_depth(s.ds, s.indices[k]))
