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
            "marching-cubes bound at --resolution, in the blocks near the keyframes' depth (meshing.block_cells), "
            "with the run's torch threads (threads). "
            "The visibility hull and those blocks come from the checkpoint; a checkpoint without them uses the "
            "keyframe poses and depth from the dataset when it can still be read, otherwise the hull's points "
            "or the camera centres and the box only."
        ),
    )
    p.add_argument("checkpoint", help="a run folder of `lrslam run`, or its checkpoint.pt")
    p.add_argument("--resolution", type=float, default=None,
                   help="grid spacing in metres, > 0 and <= 1000 (default: the run's meshing.resolution)")
    p.add_argument("--out", default=None, help="output .ply (default: mesh_<res>.ply next to the checkpoint)")
    p.add_argument("--no-cull", action="store_true", help="skip culling against the frames' view frusta")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="meshing.KEY=VALUE",
                   help="change one of the run's meshing settings for this mesh (repeatable; e.g. "
                        "meshing.block_cells=0: one dense volume)")
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


def _with_overrides(cfg: Config, items: list[str]) -> Config:
    """``cfg`` with ``meshing.KEY=VALUE`` overrides (validated like a run's); any other key is an input error: the
    checkpoint's map was made with the rest."""
    from slam.config import config_from_dict, parse_overrides
    from slam.config.presets import deep_merge

    over = parse_overrides(items)
    if set(over) - {"meshing"}:
        raise SlamInputError(f"lrslam mesh takes meshing.* overrides only, not {sorted(set(over) - {'meshing'})}")
    return config_from_dict(deep_merge(cfg.to_dict(), over)) if over else cfg


def _depths(ds, indices, bad: list):
    """The depth maps of the dataset's frames ``indices``, read one at a time (None for an unreadable one, whose
    index is appended to ``bad``)."""
    from slam.engine.frames import readable_depth

    for i in indices:
        d = readable_depth(ds, i)
        if d is None:
            bad.append(i)
        yield d


def _views(cfg: Config, ds, extra: dict, bad: list):
    """The depth maps culling tests the run's frames with (the checkpoint's ``extra`` names them), read one at a
    time; None where the run's data (``ds``, None when it cannot be read) is gone or the run's config asks for no
    depth test (the view frusta only). Unreadable frames are appended to ``bad``."""
    if ds is not None and cfg.meshing.cull_depth_test:
        return _depths(ds, extra["frame_indices"], bad)
    if cfg.meshing.cull_depth_test:
        print("note: the run's data cannot be read: culling by the view frusta only (no depth test)",
              file=sys.stderr)
    return None


def _note_unreadable(bad: list) -> None:
    if bad:
        print(f"note: {len(bad)} frame(s) of the run cannot be read: culled by their view frusta only",
              file=sys.stderr)


def _culled(mesh, cfg: Config, ds, extra: dict, intr):
    """``mesh`` culled against the view frusta of the run's frames (the checkpoint's ``extra``: their poses and
    indices), with the depth test where :func:`_views` gives depth."""
    from slam.eval import cull_mesh

    bad = []
    mesh = cull_mesh(mesh, extra["poses"].numpy(), intr, depths=_views(cfg, ds, extra, bad),
                     truncation=cfg.scene.truncation)
    _note_unreadable(bad)
    return mesh


def _hull_points(path: Path, cfg: Config, extra: dict, ds, intr):
    """``[P, 3]`` points of the run's visibility hull: the checkpoint's own, else back-projected from the keyframe
    depth the data still holds, else none (with a note)."""
    import numpy as np
    import torch

    from slam.engine.frames import readable_depth
    from slam.model.mesher import hull_points

    kf_idx = extra.get("keyframe_indices", [])
    kf_poses = extra.get("keyframe_poses", torch.zeros(0, 4, 4))
    if "hull_points" in extra:  # the run's own hull: no data needed
        return extra["hull_points"].double().numpy()
    if ds is not None and kf_idx:
        readable = [(torch.as_tensor(d), p) for d, p in zip((readable_depth(ds, i) for i in kf_idx), kf_poses)
                    if d is not None]
        return hull_points([d for d, _ in readable], [p for _, p in readable], intr,
                           cfg.meshing.hull_points_per_frame, torch.Generator().manual_seed(cfg.seed))
    print(f"note: {path} holds no hull points and the run's data cannot be read: meshing without the "
          "visibility hull (the mesh may grow surfaces where no camera looked)", file=sys.stderr)
    return np.zeros((0, 3))


def _observed(cfg: Config, extra: dict, ds, intr, hull_pts):
    """Where the keyframes observed surface, for the block extraction (None: mesh densely): the checkpoint's voxels,
    else the voxels of the keyframe depth the data still holds (read one at a time), else of the hull's points (a
    sample of that depth), else None."""
    from slam.model.mesh_blocks import Observed, observed_voxels, voxels_of

    if not cfg.meshing.block_cells:
        return None
    if "observed_voxels" in extra:  # the run's own: the mesh is the run's mesh
        return Observed(extra["observed_voxels"].long().numpy(), float(extra["observed_voxel_size"]))
    size = cfg.scene.truncation
    kf_idx = extra.get("keyframe_indices", [])
    if ds is not None and kf_idx:
        return Observed(observed_voxels(_depths(ds, kf_idx, []), extra["keyframe_poses"], intr, size), size)
    return Observed(voxels_of(hull_pts, size), size) if len(hull_pts) else None


def main(args) -> int:
    from slam.data.types import Intrinsics
    from slam.engine.runtime import set_threads
    from slam.files import replacing

    _check_resolution(args.resolution)
    path = Path(args.checkpoint)
    if path.is_dir():
        path = path / "checkpoint.pt"
    cfg, scene, extra = load_run_checkpoint(path)
    extra.pop("run", None)  # the loop's state, for --resume: not needed here
    cfg = _with_overrides(cfg, args.overrides)
    # the run's own thread count: on a shared CPU torch's default pool made each query of the walk's map 20 to 40
    # times slower (a block's 36k SDF samples: 5 ms on one thread, 80-200 ms on two next to another process)
    set_threads(cfg.threads)
    res = cfg.meshing.resolution if args.resolution is None else args.resolution
    intr = Intrinsics(**extra["intrinsics"])
    ds = None
    try:
        from slam.engine.setup import load_data

        ds = load_data(cfg)
    except SlamInputError:
        pass
    out = Path(args.out) if args.out else path.parent / f"mesh_{res:g}.ply"
    with replacing(out, "mesh") as tmp:
        nv, nf = _write_mesh(tmp, cfg, scene, extra, ds, intr, res, not args.no_cull, path)
    print(f"{nv} vertices, {nf} faces -> {out}")
    return 0


def _write_mesh(out: Path, cfg: Config, scene, extra: dict, ds, intr, res: float, cull: bool, path: Path):
    """Extract, cull and write the mesh to ``out``; ``(vertices, faces)`` written. The block extraction writes a
    PLY a block at a time, never holding the whole mesh."""
    from slam.model.mesh_blocks import extract_near
    from slam.model.mesher import Hull, extract_mesh

    pts = _hull_points(path, cfg, extra, ds, intr)
    hull = Hull(pts, cfg.meshing.hull_scale) if len(pts) >= 4 else None
    observed = _observed(cfg, extra, ds, intr, pts)
    del pts  # a million points for a long run: held no longer than needed
    extra.pop("hull_points", None)
    mcfg = cfg.meshing
    if observed is None:
        mesh = extract_mesh(scene, extra["marching_cubes_bound"], res, mcfg.batch, hull)
        if cull and len(mesh.faces):
            mesh = _culled(mesh, cfg, ds, extra, intr)
        mesh.export(out)
        return len(mesh.vertices), len(mesh.faces)
    with extract_near(scene, extra["marching_cubes_bound"], res, observed, mcfg.block_cells, mcfg.batch,
                      hull) as blocks:
        if cull and blocks.face_count:
            bad = []
            blocks.cull(extra["poses"].numpy(), intr, _views(cfg, ds, extra, bad), cfg.scene.truncation)
            _note_unreadable(bad)
        if out.suffix.lower() == ".ply":
            return blocks.write_ply(out, scene, mcfg.batch, "cpu")
        mesh = blocks.trimesh(scene, mcfg.batch, "cpu")
        mesh.export(out)
        return len(mesh.vertices), len(mesh.faces)
