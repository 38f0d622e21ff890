"""``lrslam mesh CHECKPOINT``: re-extract a mesh from a run's checkpoint at a chosen resolution."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

from slam.errors import SlamInputError

if TYPE_CHECKING:
    from slam.config import Config
    from slam.model.scene import SceneModel


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "mesh",
        help="re-extract a mesh from a run checkpoint",
        description=(
            "Rebuild the scene from a checkpoint written by `lrslam run` and run marching cubes over its "
            "marching-cubes bound at --resolution. The visibility hull uses the keyframe poses and depth "
            "from the dataset when it can still be read; otherwise the camera centres and the box only."
        ),
    )
    p.add_argument("checkpoint", help="a run folder of `lrslam run`, or its checkpoint.pt")
    p.add_argument("--resolution", type=float, default=None,
                   help="grid spacing in metres, > 0 and <= 1000 (default: the run's meshing.resolution)")
    p.add_argument("--out", default=None, help="output .ply (default: mesh_<res>.ply next to the checkpoint)")
    p.add_argument("--no-cull", action="store_true", help="skip culling against the frames' view frusta")
    p.set_defaults(func=main)


def load_run_checkpoint(path) -> tuple[Config, SceneModel, dict]:
    """Rebuild a run from the ``checkpoint.pt`` that ``lrslam run`` writes.

    Args:
        path: the checkpoint file.

    Returns:
        ``(cfg, scene, extra)``: the run's resolved config, its scene model with the saved weights (CPU, eval mode)
        and the checkpoint's ``extra`` record (poses ``[N, 4, 4]``, bounds in metres, intrinsics, keyframes).

    Raises:
        SlamInputError: no such file, not a tdfields checkpoint, or one without an lrslam config and poses.
    """
    import torch

    import tdfields
    from slam.config import config_from_dict
    from slam.model.box_resize import load_scene_state
    from slam.model.scene import SceneModel

    path = Path(path)
    try:
        ckpt = tdfields.load(path)
    except (FileNotFoundError, ValueError) as exc:
        raise SlamInputError(str(exc)) from None
    if not ckpt.get("config") or "poses" not in ckpt.get("extra", {}):
        raise SlamInputError(f"{path}: not an lrslam run checkpoint (no config or poses)")
    cfg = config_from_dict(ckpt["config"], upgrade=True)  # a checkpoint of an older version may hold moved keys
    extra = ckpt["extra"]
    scene = SceneModel(cfg, torch.tensor(extra["aabb"]))
    load_scene_state(scene, ckpt["state_dict"])  # a map whose box grew: its levels' own grids and boxes
    scene.eval()
    return cfg, scene, extra


def _check_resolution(resolution: float | None) -> None:
    """SlamInputError for a ``--resolution`` outside the run's own ``meshing.resolution`` range: 0 is not "the
    run's" (only leaving the flag out is)."""
    from slam.config.declare import METRES, Range

    allowed = Range(**METRES)
    if resolution is not None and not allowed.ok(resolution):
        raise SlamInputError(f"--resolution = {resolution:g} is out of range: must be {allowed} (metres); "
                             "leave it out for the run's meshing.resolution")


def _culled(mesh, cfg: Config, ds, extra: dict, intr):
    """``mesh`` culled against the view frusta of the run's frames (the checkpoint's ``extra``: their poses and
    indices), with the depth test where the run's data (``ds``, None when it cannot be read) still reads and the
    run's config asks for it."""
    from slam.engine.frames import readable_depth
    from slam.eval import cull_mesh

    depths = None
    if ds is not None and cfg.meshing.cull_depth_test:
        depths = [readable_depth(ds, i) for i in extra["frame_indices"]]
        bad = sum(d is None for d in depths)
        if bad:
            print(f"note: {bad} frame(s) of the run cannot be read: culled by their view frusta only",
                  file=sys.stderr)
    elif cfg.meshing.cull_depth_test:
        print("note: the run's data cannot be read: culling by the view frusta only (no depth test)",
              file=sys.stderr)
    return cull_mesh(mesh, extra["poses"].numpy(), intr, depths=depths, truncation=cfg.scene.truncation)


def main(args) -> int:
    import numpy as np
    import torch

    from slam.files import replacing
    from slam.engine.frames import readable_depth
    from slam.model.mesher import Hull, extract_mesh, hull_points

    _check_resolution(args.resolution)
    path = Path(args.checkpoint)
    if path.is_dir():
        path = path / "checkpoint.pt"
    cfg, scene, extra = load_run_checkpoint(path)
    res = cfg.meshing.resolution if args.resolution is None else args.resolution
    from slam.data.types import Intrinsics

    intr = Intrinsics(**extra["intrinsics"])
    ds = None
    try:
        from slam.engine.setup import load_data

        ds = load_data(cfg)
    except SlamInputError:
        pass
    kf_idx = extra.get("keyframe_indices", [])
    kf_poses = extra.get("keyframe_poses", torch.zeros(0, 4, 4))
    if "hull_points" in extra:  # the run's own hull: no data needed
        pts = extra["hull_points"].double().numpy()
    elif ds is not None and kf_idx:
        readable = [(torch.as_tensor(d), p) for d, p in zip((readable_depth(ds, i) for i in kf_idx), kf_poses)
                    if d is not None]
        pts = hull_points([d for d, _ in readable], [p for _, p in readable], intr,
                          cfg.meshing.hull_points_per_frame, torch.Generator().manual_seed(cfg.seed))
    else:
        pts = np.zeros((0, 3))
        print(f"note: {path} holds no hull points and the run's data cannot be read: meshing without the "
              "visibility hull (the mesh may grow surfaces where no camera looked)", file=sys.stderr)
    hull = Hull(pts, cfg.meshing.hull_scale) if len(pts) >= 4 else None
    mesh = extract_mesh(scene, extra["marching_cubes_bound"], res, cfg.meshing.batch, hull)
    if not args.no_cull and len(mesh.faces):
        mesh = _culled(mesh, cfg, ds, extra, intr)
    out = Path(args.out) if args.out else path.parent / f"mesh_{res:g}.ply"
    with replacing(out, "mesh") as tmp:
        mesh.export(tmp)
    print(f"{len(mesh.vertices)} vertices, {len(mesh.faces)} faces -> {out}")
    return 0
