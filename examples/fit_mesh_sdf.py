"""Fit a tdfields SDF to a mesh, extract it with marching cubes, and report Chamfer distance and size.

An example for NeRF/SDF users who never touch SLAM::

    python examples/fit_mesh_sdf.py --kind cp                     # a built-in torus
    python examples/fit_mesh_sdf.py --mesh bunny.ply --kind six_axis --rank 16 --out out/bunny

The mesh is scaled into ``[-1, 1]^3``. Training targets are signed distances of a pool of points (half near
the surface, half uniform), computed once: unsigned distance from a KD-tree over dense surface samples, sign
from an Embree inside test. Any kind is chosen by ``--kind``; the decoder is a small MLP.
Outputs in ``--out``: ``fitted.ply``, ``comparison.png`` (ray-cast shading, reference vs fitted), ``metrics.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

import tdfields

RANK_DEFAULTS = {"vector_matrix": 4, "cp": 8, "six_axis": 8}


def load_mesh(path: Path | None) -> trimesh.Trimesh:
    if path is None:
        mesh = trimesh.creation.torus(major_radius=0.55, minor_radius=0.22, major_sections=96, minor_sections=48)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(0.6, [1, 0, 0]))
    else:
        if not path.is_file():
            raise SystemExit(f"fit_mesh_sdf: error: mesh file not found: {path}")
        loaded = trimesh.load(path, force="mesh")
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
            raise SystemExit(f"fit_mesh_sdf: error: {path} holds no triangle mesh")
        mesh = loaded
    # into [-0.8, 0.8]^3, leaving a margin inside the field's [-1, 1]^3 box
    mesh = mesh.copy()
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    mesh.apply_scale(1.6 / mesh.extents.max())
    return mesh


def sdf_pool(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points in [-1, 1]^3 and their signed distances (negative inside), metres of the scaled mesh."""
    surface, _ = trimesh.sample.sample_surface(mesh, 400_000, seed=int(rng.integers(1 << 31)))
    tree = cKDTree(surface)
    near = surface[rng.integers(len(surface), size=n // 2)] + rng.normal(scale=0.03, size=(n // 2, 3))
    uniform = rng.uniform(-1, 1, size=(n - n // 2, 3))
    pts = np.clip(np.concatenate([near, uniform]), -1, 1)
    dist, _ = tree.query(pts, workers=-1)
    inside = mesh.contains(pts) if mesh.is_watertight else mesh.ray.contains_points(pts)
    return pts.astype(np.float32), np.where(inside, -dist, dist).astype(np.float32)


def chamfer(a: trimesh.Trimesh, b: trimesh.Trimesh, samples: int = 100_000, seed: int = 0) -> float:
    """Symmetric Chamfer distance: mean of the two mean nearest-neighbour distances between surface samples."""
    pa, _ = trimesh.sample.sample_surface(a, samples, seed=seed)
    pb, _ = trimesh.sample.sample_surface(b, samples, seed=seed + 1)
    return float(0.5 * (cKDTree(pb).query(pa, workers=-1)[0].mean() + cKDTree(pa).query(pb, workers=-1)[0].mean()))


def shade(mesh: trimesh.Trimesh, size: int = 320) -> np.ndarray:
    """Headless Lambert shading by ray casting from a fixed oblique camera: ``[size, size]`` in [0, 1]."""
    eye = np.array([1.6, -2.2, 1.6])
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    u, v = np.meshgrid(np.linspace(-0.45, 0.45, size), np.linspace(0.45, -0.45, size))
    dirs = forward + u[..., None] * right + v[..., None] * up
    dirs = (dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)).reshape(-1, 3)
    origins = np.broadcast_to(eye, dirs.shape)
    locs, ray_idx, tri_idx = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    img = np.ones(len(dirs))
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    normals = mesh.face_normals[tri_idx]
    img[ray_idx] = 0.15 + 0.85 * np.abs(normals @ light)
    return img.reshape(size, size)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--mesh", type=Path, help="any mesh trimesh reads (default: a built-in torus)")
    p.add_argument("--kind", default="six_axis", choices=sorted(tdfields.KINDS), help="field kind (default six_axis)")
    p.add_argument("--cell-size", type=float, default=0.04, help="field cell size in the [-1,1]^3 box (default 0.04)")
    p.add_argument("--channels", type=int, default=16)
    p.add_argument("--rank", type=int, help="rank for cp / six_axis / vector_matrix (default 8, 8, 4)")
    p.add_argument("--steps", type=int, default=1500, help="Adam steps (default 1500)")
    p.add_argument("--batch", type=int, default=8192)
    p.add_argument("--resolution", type=int, default=160, help="marching-cubes samples per axis (default 160)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("outputs/fit_mesh_sdf"))
    args = p.parse_args(argv)

    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    mesh = load_mesh(args.mesh)
    t0 = time.perf_counter()
    pts, sdf = sdf_pool(mesh, 300_000, rng)
    pts_t, sdf_t = torch.from_numpy(pts), torch.from_numpy(sdf)
    spec = {"kind": args.kind, "aabb": [[-1, 1]] * 3, "cell_size": args.cell_size, "channels": args.channels}
    if tdfields.KINDS[args.kind].has_rank:
        spec["rank"] = args.rank or RANK_DEFAULTS[args.kind]
    field = tdfields.build(spec)
    decoder = tdfields.MLPDecoder(field.out_dim, 1, hidden=32)
    opt = torch.optim.Adam([{"params": field.parameters(), "lr": 0.02}, {"params": decoder.parameters(), "lr": 0.005}])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, args.steps)
    gen = torch.Generator().manual_seed(args.seed)
    try:
        from tqdm import trange
    except ImportError:  # pragma: no cover
        trange = range
    bar = trange(args.steps, desc=f"fit {args.kind}")
    for step in bar:
        idx = torch.randint(len(pts_t), (args.batch,), generator=gen)
        # clamp far-field targets: the zero level set is what matters, as in truncated SDFs
        target = sdf_t[idx].clamp(-0.2, 0.2)
        loss = (decoder(field(pts_t[idx])).squeeze(-1) - target).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % 50 == 0 and hasattr(bar, "set_postfix"):
            bar.set_postfix(loss=f"{loss.item():.4f}")
    train_s = time.perf_counter() - t0

    n = args.resolution
    axis = np.linspace(-1, 1, n, dtype=np.float32)
    grid = torch.from_numpy(np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3))
    with torch.no_grad():
        values = torch.cat([decoder(field(c)).squeeze(-1) for c in grid.split(200_000)]).reshape(n, n, n).numpy()
    if not values.min() < 0 < values.max():
        print("fit_mesh_sdf: error: the fitted SDF has no zero crossing; train longer", file=sys.stderr)
        return 1
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(2 / (n - 1),) * 3)
    fitted = trimesh.Trimesh(verts - 1.0, faces, process=False)
    cd = chamfer(mesh, fitted)
    rep = tdfields.report(torch.nn.ModuleDict({"field": field, "decoder": decoder}))
    args.out.mkdir(parents=True, exist_ok=True)
    fitted.export(args.out / "fitted.ply")
    metrics = {"kind": args.kind, "chamfer": cd, "field_parameters": rep.field_parameters,
               "decoder_parameters": rep.other_parameters, "train_seconds": train_s, "steps": args.steps,
               "complexity": field.complexity, "grid_shape": list(field.grid_shape)}
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(8, 4))
        for ax, m, title in zip(axes, (mesh, fitted), ("reference mesh", f"{args.kind}: Chamfer {cd * 100:.2f} (x1e-2)")):
            ax.imshow(shade(m), cmap="gray", vmin=0, vmax=1)
            ax.set_title(title, fontsize=9)
            ax.axis("off")
        fig.suptitle(f"{rep.field_parameters:,} field parameters ({field.complexity}), {args.steps} steps", fontsize=9)
        fig.tight_layout()
        fig.savefig(args.out / "comparison.png", dpi=110)
    except Exception as exc:  # the picture is a convenience; the metrics above are the result
        print(f"fit_mesh_sdf: warning: no picture ({exc})", file=sys.stderr)
    print(rep)
    print(f"Chamfer distance: {cd:.5f} (mesh units, box [-1,1]^3)   field parameters: {rep.field_parameters:,}   "
          f"training: {train_s:.1f} s   outputs: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
