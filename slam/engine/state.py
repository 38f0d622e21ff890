"""What the loop accumulates frame by frame (:class:`RunState`), and the error of a run with too many bad frames."""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field

import torch

from slam.errors import SlamInputError


@dataclass
class RunState:
    """Everything the loop accumulates (and a checkpoint keeps): one entry per processed frame in ``est``
    (``[7]`` poses), ``trusted`` (False where tracking was lost or the frame was skipped) and ``frame_times``
    (seconds); ``events`` (skipped frames, fallbacks, recoveries); ``bad_frames`` (unreadable frames);
    ``prev_depth``: ``[H, W]`` depth (metres) of the last trusted frame with depth, at position ``prev_depth_k``
    (ICP's reference; not stored in a checkpoint, read again from the data)."""

    est: list = field(default_factory=list)
    trusted: list = field(default_factory=list)
    frame_times: list = field(default_factory=list)
    events: list = field(default_factory=list)
    bad_frames: int = 0
    initialized: bool = False  # the first-frame warm-up has run (on the first frame with depth)
    prev_depth_k: int = -1  # position of the last trusted frame with depth (ICP's reference)
    reloc_tried_at: int = -1  # position of the last relocalisation attempt
    last_mapped: int = -1  # position of the last frame submitted for mapping (slam.engine.schedule)
    last_keyframe: int = -1  # position of the last frame submitted as a keyframe (slam.engine.schedule)
    dropped: list = field(default_factory=list)  # data.realtime: dataset frames that arrived and were never taken
    latency: list = field(default_factory=list)  # data.realtime: seconds from a processed frame's arrival to its pose
    tracking: list = field(default_factory=list)  # per tracked frame: loss, iterations, inlier share
    sizes: list = field(default_factory=list)  # per processed frame: [parameters, field bytes] of the scene then
    prev_depth: torch.Tensor | None = field(default=None, repr=False, metadata={"transient": True})
    # loops.enabled, after the last frame: every frame's loop-corrected [N, 4, 4] camera-to-world and the summary
    corrected: object = field(default=None, repr=False, metadata={"transient": True})
    loop_summary: dict | None = field(default=None, repr=False, metadata={"transient": True})
    # loops.refine_iters: the map re-fitted on the corrected poses (slam.engine.refine), once; its statistics
    refined: dict | None = None

    def last_trusted(self) -> int:
        """Position of the last trusted frame (-1: none yet)."""
        return next((j for j in range(len(self.trusted) - 1, -1, -1) if self.trusted[j]), -1)

    def state_dict(self) -> dict:
        """Plain lists, numbers and one ``[N, 7]`` tensor of poses (``torch.load(weights_only=True)`` reads it)."""
        out = {f.name: copy.deepcopy(getattr(self, f.name)) for f in dataclasses.fields(self)
               if f.name != "est" and not f.metadata.get("transient")}
        out["est"] = torch.stack(self.est) if self.est else torch.zeros(0, 7)
        return out

    @classmethod
    def from_state_dict(cls, state: dict) -> "RunState":
        """The inverse of :meth:`state_dict` (``prev_depth`` stays None: the caller reads it again)."""
        st = dict(state)
        est = st.pop("est")
        out = cls(**st)
        out.est = [p.clone() for p in est]
        out.sizes = [None] * (len(out.est) - len(out.sizes)) + out.sizes  # a checkpoint from before sizes were kept
        return out


@dataclass
class TrackResult:
    """``pose``: ``[7]`` best-loss pose; ``loss``: its loss (NaN if none was finite); ``ok``; ``message``: why it
    stopped early; ``iters``: iterations run; ``inliers``: share of the rays kept by the outlier rule at the
    best iteration."""

    pose: torch.Tensor
    loss: float
    ok: bool
    message: str = ""
    iters: int = 0
    inliers: float = float("nan")


class TooManyBadFrames(SlamInputError):
    """More than ``data.max_bad_fraction`` of the frames read so far could not be read."""


def check_bad_frames(st: RunState, total: int, max_fraction: float) -> None:
    """Raise :class:`TooManyBadFrames` once more than ``max_fraction`` of the run's ``total`` frames could not be
    read (``data.max_bad_fraction``)."""
    if st.bad_frames > max_fraction * total:
        raise TooManyBadFrames(
            f"{st.bad_frames} of the first {len(st.est)} frames could not be read, more than "
            f"data.max_bad_fraction = {max_fraction} of the {total} frames; see the events")


def live_ate(est: list, gt: torch.Tensor | None) -> float:
    """ATE RMSE in metres of the poses ``est`` (``[7]`` each) so far against ``gt`` ``[N, 4, 4]`` (its first
    ``len(est)``); NaN before three frames, without ground truth, or when it cannot be computed."""
    if gt is None or len(est) < 3:
        return float("nan")
    from slam.core.pose import pose_to_matrix
    from slam.eval import ate

    poses = pose_to_matrix(torch.stack(est)).numpy()
    try:
        return ate(poses, gt[: len(poses)].numpy()).rmse
    except SlamInputError:
        return float("nan")
