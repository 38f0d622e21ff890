"""Mapping (docs/slam.md, "The pipeline (as implemented)", Mapping): optimise the scene (and, with BA, the window poses)
on a keyframe window.

The optimiser is rebuilt at every call (Adam, default betas): decoders + beta, geometry and appearance fields
at their own learning rates (x ``lr_first_factor`` on the first frame, which runs ``iters_first`` iterations).
Each iteration draws ``pixels // n_frames`` pixels from every window frame over the full image. The SDF and
depth terms use rays with depth; the colour term every ray whose measured surface is inside the box.
Joint BA (after more than ``ba_min_keyframes`` keyframes) optimises one 7-d pose per window frame except the
oldest (the gauge) and frame 0 (pinned to ground truth).

With ``mapping.optimizer_state: persistent`` (ours; Co-SLAM keeps one map optimiser for the whole run) the map's
Adam moments are carried from one call to the next in a :class:`MapMoments` the caller holds, from the first call
after the warm-up on (the warm-up's rates are x ``lr_first_factor``); the BA poses, new tensors every call, get a
fresh Adam each call. A fresh Adam's first step moves every parameter the batch touched by the full learning rate,
whatever its gradient (its moments are that one gradient); carried moments scale each step by the gradients seen so
far (docs/slam.md, "Carried map moments").
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from slam.config import Config
from slam.engine.keyframes import Keyframe, KeyframeStore, keyframe_matrices, overlapping_keyframes, select_window
from slam.core.losses import total_loss
from slam.core.optim import adam
from slam.core.camera import sample_pixels
from slam.core.pose import normalize_pose, pose_to_matrix
from slam.core.rendering import render_pixels


@dataclass
class MapResult:
    """``pose``: ``[7]`` (possibly BA-refined) current pose; ``window``: frame positions used; ``loss``: the last
    finite loss; ``ok``: at least one step was taken; ``skipped``: steps skipped for a non-finite loss or
    gradient."""

    pose: torch.Tensor
    window: list[int]
    loss: float
    ok: bool
    skipped: int = 0


class MappingAborted(Exception):
    """A mapping call ended early by its ``should_stop`` (the run is being abandoned)."""


def finite_step(loss: torch.Tensor, params: list[torch.Tensor]) -> bool:
    """Whether ``loss`` and every gradient of ``params`` (after ``loss.backward()``) are finite."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return bool(torch.isfinite(loss))
    norms = torch._foreach_norm(grads)  # one fused pass over the gradients
    return bool(torch.isfinite(loss) & torch.isfinite(torch.stack(norms)).all())


def _window(keyframes: KeyframeStore, depth, pose, intrinsics, mc, generator, first: bool) -> list[int]:
    """Positions in the store of the keyframes optimised with the current frame (none on the warm-up)."""
    if first or len(keyframes) == 0:
        return []
    if mc.keyframe_selection == "overlap":
        with torch.no_grad():
            overlap = overlapping_keyframes(
                depth.cpu(), pose_to_matrix(pose.cpu()), keyframe_matrices(keyframes.poses()),
                intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, intrinsics.height,
                intrinsics.width, mc.overlap_pixels, mc.overlap_samples, 20, generator)
    else:
        overlap = torch.ones(len(keyframes), dtype=torch.bool)
    return select_window(len(keyframes), overlap, mc.window_size, generator)


def _window_frames(keyframes: KeyframeStore, window: list[int], index: int, color, depth, pose):
    """The window's images ``[F, H, W, 3]`` / ``[F, H, W]`` and poses ``[F, 7]`` on the device, and its frame
    positions, the current frame last."""
    device = depth.device
    frames = [keyframes.frames[i] for i in window]
    frame_ids = [kf.index for kf in frames] + [index]
    poses0 = torch.stack([kf.pose for kf in frames] + [pose.cpu()]).to(device)
    images = [kf.float_images() for kf in frames]  # one read each of the keyframes spilled to disk
    colors = torch.stack([c.to(device) for c, _ in images] + [color.to(device)])
    depths = torch.stack([d.to(device) for _, d in images] + [depth.to(device)])
    return colors, depths, poses0, frame_ids


def _free_poses(frame_ids: list[int], ba: bool) -> torch.Tensor:
    """``[F]`` which window poses BA optimises: all but the oldest (the gauge) and frame 0 (pinned)."""
    free = torch.zeros(len(frame_ids), dtype=torch.bool)
    if ba:
        free[1:] = True
        free &= torch.tensor([fid != 0 for fid in frame_ids])
    return free


class MapMoments:
    """The map's Adam state between mapping calls (``mapping.optimizer_state: persistent``): ``state`` maps each
    scene parameter's name to its Adam state after the last call (``step``, ``exp_avg``, ``exp_avg_sq``; None: none
    yet, or the map was grown since). By name, not by Adam's group index: the rate groups can change from call to call
    (``lr_scaling: lift``). Plain tensors, saved in checkpoints with the mapper's state."""

    def __init__(self, state: dict | None = None):
        self.state = state

    def reset(self) -> None:
        """Forget the moments (a grown map's factors have other shapes): the next call starts a fresh Adam."""
        self.state = None

    def check(self, scene) -> None:
        """Raise RuntimeError unless every moment belongs to a parameter of ``scene`` and has its shape (checked when
        a checkpoint is loaded and before a call loads them: a grown map resets them, so they fit the map they were
        kept for)."""
        params = dict(scene.named_parameters())
        for name, st in (self.state or {}).items():
            if name not in params:
                raise RuntimeError(f"carried Adam moments of {name}, which this scene has no parameter of")
            for part in ("exp_avg", "exp_avg_sq"):
                if tuple(st[part].shape) != tuple(params[name].shape):
                    raise RuntimeError(f"carried Adam moments of {name} ({part}) have shape {tuple(st[part].shape)}, "
                                       f"the parameter {tuple(params[name].shape)} (a grown map must reset them)")

    def cpu_state(self) -> dict | None:
        """``state`` with its tensors on the CPU (a checkpoint resumes on any device; the pipe to a mapper process
        carries CPU tensors). No copy where they are there already: a call never writes into the state it was
        given (it loads a copy) and replaces ``state`` when it ends."""
        if self.state is None:
            return None
        return {name: {k: v.detach().cpu() for k, v in st.items()} for name, st in self.state.items()}


class _Optimiser:
    """The call's optimisers: Adam over the scene's groups (its state from ``moments`` when carried) and, with BA,
    a fresh Adam over the free window poses ``cam`` ``[F_free, 7]`` (None without BA); ``params`` all of them."""

    def __init__(self, scene, cfg: Config, first: bool, poses0, free, moments: MapMoments | None):
        mc = cfg.mapping
        factor = mc.lr_first_factor if first else 1.0
        # the warm-up starts from the random initialisation, where the step scale is ~40x (CP): plain rates there
        groups = scene.param_groups(cfg, factor, "none" if first else mc.lr_scaling)
        self.moments = moments if (mc.optimizer_state == "persistent" and not first) else None
        self.cam, self.poses, cam_groups = None, None, []
        if bool(free.any()):
            self.cam = torch.nn.Parameter(poses0[free].clone())
            cam_groups = [{"params": [self.cam], "lr": mc.joint_opt_cam_lr}]
        if self.moments is None:  # one Adam over everything, as ESLAM
            self.map = adam(groups + cam_groups)
        else:
            self.map = adam(groups)
            self.names = {p: n for n, p in scene.named_parameters()}
            self.moments.check(scene)
            self._load(self.moments.state or {})
            self.poses = adam(cam_groups) if cam_groups else None
        self.params = [p for g in groups + cam_groups for p in g["params"]]

    def _load(self, state: dict) -> None:
        for p, name in self.names.items():
            if name in state:
                # on the parameter's device: a checkpoint's moments are on the CPU (fused Adam wants them beside it)
                self.map.state[p] = {k: v.detach().to(p.device, copy=True) for k, v in state[name].items()}

    def window_poses(self, poses0: torch.Tensor, free: torch.Tensor) -> torch.Tensor:
        """``[F, 7]`` the window's poses this iteration: ``poses0`` with the free ones BA's (differentiable)."""
        if self.cam is None:
            return poses0
        poses = poses0.clone()
        poses[free] = self.cam
        return poses

    def zero_grad(self) -> None:
        for opt in (self.map, self.poses):
            if opt is not None:
                opt.zero_grad(set_to_none=True)

    def step(self) -> None:
        for opt in (self.map, self.poses):
            if opt is not None:
                opt.step()

    def keep(self) -> None:
        """After the call: the map optimiser's state into the moments (when carried)."""
        if self.moments is not None:
            self.moments.state = {self.names[p]: dict(st) for p, st in self.map.state.items()}


def mapping_loss(scene, colors, depths, poses, intrinsics, cfg: Config, per_frame: int, generator):
    """The mapping loss of one iteration (a scalar tensor): ``per_frame`` fresh pixels of every frame of ``colors``
    ``[F, H, W, 3]`` in [0, 1], ``depths`` ``[F, H, W]`` metres, at ``poses`` ``[F, 7]`` camera-to-world; None when no
    ray's surface is inside the box."""
    F, H, W = depths.shape
    device = depths.device
    v, u = sample_pixels(H, W, per_frame * F, 0, 0, generator)
    fidx = torch.arange(F).repeat_interleave(per_frame)
    v, u, fidx = v.to(device), u.to(device), fidx.to(device)
    rendered = render_pixels(scene, u=u, v=v, depth=depths[fidx, v, u], color=colors[fidx, v, u],
                             c2w=pose_to_matrix(poses)[fidx], intrinsics=intrinsics, rendering=cfg.rendering,
                             truncation=cfg.scene.truncation, perturb=cfg.rendering.perturb, generator=generator,
                             depth_required=cfg.mapping.rays_without_depth == "skip")
    if rendered is None:
        return None
    out, D, C = rendered
    return total_loss(out.sdf, out.z, out.depth, out.color, D, C, cfg.scene.truncation, cfg.mapping.weights,
                      fused=cfg.rendering.fused)[0]


def _write_back(cam, free, window: list[int], keyframes: KeyframeStore, pose):
    """BA's refined poses into the window's keyframes; returns the current frame's (``pose`` without BA)."""
    if cam is None:
        return pose
    new = normalize_pose(cam.detach().cpu())
    if not bool(torch.isfinite(new).all()):
        return pose
    refined = pose
    for k, pos in enumerate(torch.nonzero(free).flatten().tolist()):
        if pos < len(window):
            keyframes.frames[window[pos]].pose = new[k].clone()
        else:
            refined = new[k].clone()
    return refined


def keep_keyframe(keyframes: KeyframeStore, index: int, color: torch.Tensor, depth: torch.Tensor, pose: torch.Tensor,
                  result: MapResult, keyframe: bool, drop: bool = True) -> None:
    """After the mapping call of frame ``index``: store it in ``keyframes`` (images on the CPU, with the call's
    BA-refined pose, or ``pose`` ``[7]`` for frame 0) when the schedule made it a keyframe and the call took a
    step. The one rule for every place a call runs (thread, inline, the mapper's process), so their stores agree;
    ``drop`` False: a mirror, which takes the drops of the store it mirrors (:meth:`KeyframeStore.follow`)."""
    if keyframe and result.ok:
        kept = result.pose if index > 0 else pose
        keyframes.add(Keyframe(index, color.cpu(), depth.cpu(), kept.cpu().clone()), drop=drop)


def map_frame(
    scene,
    index: int,
    color: torch.Tensor,
    depth: torch.Tensor,
    pose: torch.Tensor,
    intrinsics,
    keyframes: KeyframeStore,
    cfg: Config,
    generator: torch.Generator,
    first: bool = False,
    should_stop=None,
    moments: MapMoments | None = None, iters: int = 0,
) -> MapResult:
    """One mapping call for frame ``index``.

    Args:
        scene: :class:`slam.model.scene.SceneModel` (optimised in place).
        color, depth: current frame ``[H, W, 3]`` / ``[H, W]`` on the scene's device.
        pose: ``[7]`` current estimated pose.
        keyframes: the store (refined poses written back when BA runs).
        first: the first-frame warm-up (``iters_first``, learning rates x ``lr_first_factor``).
        should_stop: checked before every iteration; True raises :class:`MappingAborted` (a second Ctrl-C: the
            call's work is thrown away, so the map is left mid-call and must not be saved).
        moments: the map's Adam state carried between calls (``mapping.optimizer_state: persistent``; read and
            updated here). None: every call starts a fresh Adam, whatever the config says.
        iters: iterations of this call (0: ``mapping.iters``; the warm-up always takes ``iters_first``).

    Returns: :class:`MapResult` with the (possibly BA-refined) current pose.
    """
    mc = cfg.mapping
    window = _window(keyframes, depth, pose, intrinsics, mc, generator, first)
    colors, depths, poses0, frame_ids = _window_frames(keyframes, window, index, color, depth, pose)
    free = _free_poses(frame_ids, mc.joint_opt and not first and len(keyframes) > mc.ba_min_keyframes)
    opt = _Optimiser(scene, cfg, first, poses0, free, moments)
    steps, skipped, last = 0, 0, float("nan")
    each = max(mc.pixels // len(frame_ids), 1)  # pixels per window frame
    free_dev = free.to(depth.device)
    for _ in range(mc.iters_first if first else iters or mc.iters):
        if should_stop is not None and should_stop():
            raise MappingAborted(f"mapping call of frame {index} aborted")
        loss = mapping_loss(scene, colors, depths, opt.window_poses(poses0, free_dev), intrinsics, cfg, each, generator)
        if loss is None:
            break
        opt.zero_grad()
        if not bool(torch.isfinite(loss)):
            skipped += 1  # nothing is stepped: the map (and Adam's state) stay as they were
            continue
        loss.backward()
        if not finite_step(loss, opt.params):
            skipped += 1
            opt.zero_grad()
            continue
        opt.step()
        steps += 1
        last = float(loss.detach())
    opt.keep()
    if steps == 0:
        return MapResult(pose, frame_ids, float("nan"), False, skipped)
    return MapResult(_write_back(opt.cam, free, window, keyframes, pose), frame_ids, last, True, skipped)
