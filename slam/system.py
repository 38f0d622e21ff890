"""The SLAM loop: tracking every frame, mapping every ``every_frame`` frames (and the last), keyframes, mesh
extraction. Writing a run's outputs lives in :mod:`slam.outputs`, a whole run to a folder in :mod:`slam.runner`.

Sequential by design, like ESLAM in practice (its tracker waits for the mapper at every mapped frame).
Robustness: a frame without valid depth is not tracked or mapped (its pose is the constant-velocity
prediction); a tracking result that is not finite falls back to the prediction; a non-finite mapping loss
stops that mapping call before any update. Each such event is logged and listed in ``metrics.json``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from slam.config import Config
from slam.errors import SlamInputError
from slam.keyframes import Keyframe, KeyframeStore
from slam.mapper import map_frame
from slam.pose import constant_velocity, matrix_to_pose, pose_to_matrix
from slam.observers import FrameRecord, Observer
from slam.runtime import keep_freed_memory, set_threads
from slam.scene import SceneModel, parameter_counts, scene_aabb
from slam.tracker import track_frame

log = logging.getLogger("slam")


# --------------------------------------------------------------------------------------------------- set-up
def resolve_device(name: str) -> torch.device:
    """``cpu`` / ``cuda`` / ``cuda:N``; a GPU request without CUDA raises :class:`SlamInputError`."""
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise SlamInputError(f"device '{name}' requested but CUDA is not available on this machine; use --device cpu")
        idx = int(name.split(":")[1]) if ":" in name else 0
        if idx >= torch.cuda.device_count():
            raise SlamInputError(f"device '{name}' requested but only {torch.cuda.device_count()} GPU(s) exist")
    elif name != "cpu":
        raise SlamInputError(f"device must be cpu or cuda, got '{name}'")
    return torch.device(name)


def load_data(cfg: Config):
    """Open the dataset the config names (the bundled synthetic sequence when ``data.path`` is null)."""
    from slam.data import load_dataset
    from slam.data.loader import detect_layout

    path = cfg.data.path
    kind = cfg.data.kind
    if path is None:
        if kind not in ("auto", "synthetic", "replica"):
            raise SlamInputError(f"preset '{cfg.name}' reads {kind} data: pass its folder with --data PATH")
        from slam.data.synthetic import default_sequence

        path = str(default_sequence())
    if kind == "synthetic":
        kind = "replica"
    p = Path(path).expanduser()
    if not p.exists():
        raise SlamInputError(f"data folder not found: {p}")
    found = detect_layout(p)
    if kind != "auto" and found != kind:
        raise SlamInputError(f"preset '{cfg.name}' expects {kind} data but {p} looks like {found} data "
                             f"(pick a {found} preset or data.kind=auto)")
    try:
        ds = load_dataset(p, kind=found, **cfg.data.options)
    except SlamInputError:
        raise
    except (ValueError, FileNotFoundError, KeyError, OSError, TypeError) as exc:
        raise SlamInputError(f"{p}: cannot be read as {found} data: {exc}") from None
    if len(ds) == 0:
        raise SlamInputError(f"{p}: the dataset has no frames")
    return ds


def frame_indices(n: int, cfg: Config) -> list[int]:
    idx = list(range(0, n, max(cfg.data.stride, 1)))
    if cfg.data.max_frames:
        idx = idx[: cfg.data.max_frames]
    return idx


def auto_bound(depths: list[torch.Tensor], c2w0: torch.Tensor, percentile: float, margin: float) -> list[list[float]]:
    """Scene box from the first frames' depth (``scene.bound: auto``).

    A cube centred on the first camera whose half-size is the ``percentile``-th percentile of the valid depth
    of the given frames plus ``margin`` metres. It holds everything those frames see from any orientation at
    the start, so a camera that mostly rotates (or moves less than ``margin``) stays inside without hand-tuned
    boxes. Lengths in metres.
    """
    vals = torch.cat([d[d > 0].flatten().float().cpu() for d in depths])
    if vals.numel() == 0:
        raise SlamInputError("bound=auto: the first frames have no valid depth; give scene.bound explicitly")
    r = float(np.percentile(vals.numpy(), percentile)) + margin
    c = c2w0[:3, 3].double().tolist()
    return [[c[a] - r, c[a] + r] for a in range(3)]


# --------------------------------------------------------------------------------------------------- loop
@dataclass
class RunState:
    est: list = field(default_factory=list)  # [7] tensors, one per processed frame
    frame_times: list = field(default_factory=list)
    events: list = field(default_factory=list)


class SLAM:
    """Tracking + mapping over a dataset with one scene model.

    Args:
        cfg: resolved config.
        dataset: a ``slam.data`` dataset.
        device: torch device.
    """

    def __init__(self, cfg: Config, dataset, device: torch.device | str = "cpu"):
        self.cfg = cfg
        self.ds = dataset
        self.device = torch.device(device)
        self.indices = frame_indices(len(dataset), cfg)
        set_threads(cfg.threads)
        if cfg.keep_freed_memory:
            keep_freed_memory()
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        gt = getattr(dataset, "gt_poses", None)
        self.gt = None if gt is None else torch.as_tensor(np.asarray(gt), dtype=torch.float32)[self.indices]
        first = dataset[self.indices[0]]
        self.intr = first.intrinsics
        self.c2w0 = self._gt_or_identity(0)
        if cfg.scene.bound == "auto":
            k = max(1, min(cfg.scene.bound_auto_frames, len(self.indices)))
            depths = [first.depth] + [dataset[self.indices[i]].depth for i in range(1, k)]
            self.bound = auto_bound(depths, self.c2w0, cfg.scene.bound_auto_percentile, cfg.scene.bound_auto_margin)
            log.info("bound=auto -> %s", [[round(v, 3) for v in r] for r in self.bound])
        else:
            self.bound = [list(map(float, r)) for r in cfg.scene.bound]
        self.mc_bound = cfg.scene.marching_cubes_bound or self.bound
        self.aabb = scene_aabb(self.bound, cfg.scene.bound_dividable)
        self.scene = SceneModel(cfg, self.aabb).to(self.device)
        self.keyframes = KeyframeStore()
        self.state = RunState()

    def _gt_or_identity(self, k: int) -> torch.Tensor:
        if self.gt is not None and bool(torch.isfinite(self.gt[k]).all()):
            return self.gt[k].clone()
        return torch.eye(4)

    def live_ate(self) -> float:
        if self.gt is None or len(self.state.est) < 3:
            return float("nan")
        from slam.eval import ate

        est = pose_to_matrix(torch.stack(self.state.est)).numpy()
        try:
            return ate(est, self.gt[: len(est)].numpy()).rmse
        except SlamInputError:
            return float("nan")

    def _event(self, k: int, what: str) -> None:
        log.warning("frame %d: %s", self.indices[k], what)
        self.state.events.append({"frame": int(self.indices[k]), "event": what})

    def step(self, k: int) -> FrameRecord:
        """Process the k-th selected frame (track, then map if scheduled); returns what happened."""
        cfg = self.cfg
        frame = self.ds[self.indices[k]]
        color = torch.as_tensor(frame.color, dtype=torch.float32).to(self.device)
        depth = torch.as_tensor(frame.depth, dtype=torch.float32).to(self.device)
        depth = torch.where(torch.isfinite(depth), depth, torch.zeros_like(depth))
        has_depth = bool((depth > 0).any())
        est = self.state.est
        if k == 0:
            pose = matrix_to_pose(self._gt_or_identity(0))
        else:
            if cfg.tracking.const_speed and k >= 2:
                init = constant_velocity(est[-1], est[-2])
            else:
                init = est[-1].clone()
            if not has_depth:
                self._event(k, "no valid depth: not tracked or mapped, pose from constant velocity")
                pose = init
            else:
                res = track_frame(self.scene, color, depth, self.intr, init, cfg, self.gen)
                if not res.ok:
                    self._event(k, f"tracking failed ({res.message}): constant-velocity pose used")
                pose = res.pose
        est.append(pose.cpu())
        tracked = k > 0 and has_depth
        mapped = False
        last = k == len(self.indices) - 1
        if has_depth and (k % cfg.mapping.every_frame == 0 or last):
            mapped = True
            res = map_frame(self.scene, k, color, depth, est[-1], self.intr, self.keyframes, cfg, self.gen,
                            first=(k == 0))
            if not res.ok:
                self._event(k, "non-finite mapping loss: mapping call skipped")
            elif k > 0:
                est[-1] = res.pose.cpu()
            if k % cfg.mapping.keyframe_every == 0:
                self.keyframes.add(Keyframe(k, color.cpu(), depth.cpu(), est[-1].clone()))
        return FrameRecord(k=k, frame=int(self.indices[k]), color=color, depth=depth,
                           pose=pose_to_matrix(est[-1]), gt=self.gt[k] if self.gt is not None else None,
                           tracked=tracked, mapped=mapped)

    def run(self, progress: bool = True, observers: Sequence[Observer] = ()) -> RunState:
        """Process every selected frame, with a progress bar (frame, live ATE, frame time) and the observers'
        ``on_frame`` after each one."""
        from tqdm import tqdm

        bar = tqdm(range(len(self.indices)), disable=not progress, unit="frame", dynamic_ncols=True,
                   desc=f"lrslam [{self.cfg.representation}]")
        for k in bar:
            t0 = time.perf_counter()
            rec = self.step(k)
            dt = time.perf_counter() - t0
            self.state.frame_times.append(dt)
            rec.dt = dt
            rec.ate_m = self.live_ate()
            for obs in observers:
                obs.on_frame(self, rec)
            bar.set_postfix_str(f"frame {self.indices[k]}  ATE {rec.ate_m * 100:.2f} cm  {dt:.2f} s/frame")
        bar.close()
        return self.state

    # ----------------------------------------------------------------------------------------------- results
    def poses_matrix(self) -> np.ndarray:
        return pose_to_matrix(torch.stack(self.state.est)).numpy()

    def keyframe_poses(self) -> np.ndarray:
        return pose_to_matrix(self.keyframes.poses()).numpy() if len(self.keyframes) else np.zeros((0, 4, 4))

    def mesh(self, resolution: float | None = None, cull: bool | None = None):
        """Extract (and cull) the mesh with the config's meshing settings."""
        from slam.mesher import Hull, extract_mesh, hull_points

        mcfg = self.cfg.meshing
        res = resolution or mcfg.resolution
        kf_c2w = [torch.from_numpy(T) for T in self.keyframe_poses()]
        pts = hull_points([kf.depth for kf in self.keyframes.frames], kf_c2w, self.intr, mcfg.hull_points_per_frame,
                          torch.Generator().manual_seed(self.cfg.seed))
        hull = Hull(pts, mcfg.hull_scale) if len(pts) >= 4 else None
        mesh = extract_mesh(self.scene, self.mc_bound, res, mcfg.batch, hull, self.device)
        if (mcfg.cull if cull is None else cull) and len(mesh.faces):
            mesh = self._cull(mesh)
        return mesh

    def _cull(self, mesh):
        """Cull with ``slam.eval.cull_mesh`` using every processed frame's estimated pose (and depth if configured)."""
        from slam.eval import cull_mesh

        depths = None
        if self.cfg.meshing.cull_depth_test:
            depths = [np.asarray(self.ds[i].depth, dtype=np.float32) for i in self.indices]
        return cull_mesh(mesh, self.poses_matrix(), self.intr, depths=depths, truncation=self.cfg.scene.truncation)

    def checkpoint_extra(self) -> dict:
        ts = getattr(self.ds, "timestamps", None)
        return {
            "poses": torch.from_numpy(self.poses_matrix()).float(),
            "frame_indices": list(self.indices),
            "timestamps": [float(ts[i]) for i in self.indices] if ts is not None else [],
            "bound": self.bound,
            "marching_cubes_bound": [list(map(float, r)) for r in self.mc_bound],
            "aabb": self.aabb.tolist(),
            "intrinsics": self.intr.as_dict(),
            "keyframe_indices": [int(self.indices[kf.index]) for kf in self.keyframes.frames],
            "keyframe_poses": torch.from_numpy(self.keyframe_poses()).float(),
        }
