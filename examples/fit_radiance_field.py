"""Fit a small NeRF-style radiance field (tdfields density + appearance) to posed RGB(-D) images.

No nerfstudio, no SLAM: ground-truth poses, every 8th image held out, PSNR/SSIM on the held-out views::

    python examples/fit_radiance_field.py --dataset synthetic --kind six_axis        # the synthetic room, small
    python examples/fit_radiance_field.py --data ../shared/data/tum_fr1_rpy --dataset tum --size 120x160 \\
        --kind cp --budget 500000 --resolution 128 --out out/rpy_cp
    python examples/fit_radiance_field.py --budget 100000 --compare cp six_axis triplane --out out/synth

Model: density = softplus(MLP(density field)) (1/m, zero outside the box), colour = MLP(appearance field)
(sigmoid, diffuse: no view direction). ``--kind`` picks the tdfields kind of both fields; ``hybrid`` is CP
density + Six-axis appearance (LRSLAM's pairing). The scene box is the back-projected depth of all frames; depth
also sets each image's near/far range (and, with ``--depth-weight``, an L1 depth loss), nothing else.
Rendering: stratified samples between near and far, alpha compositing over a black (default) or white
background. Black by default because indoor rays end on surfaces and the rooms are darker than white: a white
one makes the first steps raise density all along every ray to darken it (the test's room: 26.0, not 27.4 dB).
``--budget P`` matches kinds by total parameters: kinds with a rank keep ``--resolution`` and choose the rank,
dense grids and tri-planes choose the resolution; the achieved counts are in the metrics.
Outputs in ``--out``: ``metrics.json``, ``renders/view_NNN.png`` (ground truth | render); with ``--compare``
one folder per kind plus ``compare.json`` and ``compare.md``.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
import torch.nn.functional as F
from skimage.metrics import peak_signal_noise_ratio, structural_similarity
from tqdm import tqdm

import tdfields

PROG = "fit_radiance_field"
KIND_NAMES = sorted(tdfields.KINDS) + ["hybrid"]
DATASETS = ("synthetic", "replica", "tum", "7scenes", "scannet")
RANKS = {"vector_matrix": 4, "cp": 16, "six_axis": 8}  # ranks without --budget
DENSITY_CHANNELS, APPEARANCE_CHANNELS = 8, 16
# density = DENSITY_SCALE * softplus(raw + DENSITY_SHIFT) per metre: 0.45/m at init, so a 3 m ray starts about 3/4
# opaque and the colour head gets real gradients from step one (at 0.06/m Adam blew its tiny ones up to full steps
# and the hybrid's head collapsed to grey); the scale lets a raw output of a few units make a surface opaque
DENSITY_SCALE, DENSITY_SHIFT = 25.0, -4.0
HOLD_OUT = 8  # every 8th image is a test view (the LLFF convention)


def fail(msg: str):
    """Leave with a one-line error (exit status 1), never a traceback."""
    raise SystemExit(f"{PROG}: error: {msg}")


# --- data ------------------------------------------------------------------------------------------------------
def resize_views(color, depth, k, size):
    """Area-downsample ``color [N, H, W, 3]``, nearest ``depth [N, H, W]`` to ``size = (h, w)``; intrinsics with
    pixel centres at integers: ``c' = (c + 0.5) s - 0.5`` (plain ``c s`` shifts the image by up to half a pixel)."""
    h, w = size
    sx, sy = w / k.width, h / k.height
    color = F.interpolate(color.permute(0, 3, 1, 2), size=size, mode="area").permute(0, 2, 3, 1)
    depth = F.interpolate(depth[:, None], size=size, mode="nearest")[:, 0]
    intr = type(k)(k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5, (k.cy + 0.5) * sy - 0.5, h, w)
    return color.contiguous(), depth.contiguous(), intr


def load_views(args) -> dict:
    """All frames with a valid pose: ``color [N, H, W, 3]`` in [0, 1], ``depth [N, H, W]`` metres (0 = none),
    ``poses [N, 4, 4]`` camera-to-world (OpenCV axes), ``intrinsics`` (of the possibly resized images)."""
    from slam.data import load_dataset
    from slam.errors import SlamInputError

    with tempfile.TemporaryDirectory(prefix="radiance_synth_") as tmp:
        path = args.data
        if path is None:
            if args.dataset != "synthetic":
                fail(f"--data DIR is required for --dataset {args.dataset}")
            from slam.data.synthetic import SynthConfig, generate

            h, w = args.size or (60, 80)
            frames = args.frames or 24
            # a quarter loop around the room: views 5.6 degrees apart, held-out views between training ones
            path = generate(Path(tmp), SynthConfig(frames=frames, height=h, width=w, loop_frames=4 * frames))
        elif not path.is_dir():
            fail(f"{path}: dataset folder not found")
        # TUM colour is undistorted, which leaves a black rim: crop it as ESLAM does
        options = {"crop_edge": 8} if args.dataset == "tum" else {}
        try:
            ds = load_dataset(path, kind="replica" if args.dataset == "synthetic" else args.dataset,
                              max_frames=args.frames, **options)
            frames = [f for f in ds if f.has_valid_pose]
        except SlamInputError as exc:
            fail(str(exc))
    if len(frames) < 2:
        fail(f"{path}: need at least 2 frames with poses, found {len(frames)}")
    color = torch.stack([f.color for f in frames])
    depth = torch.stack([f.depth for f in frames])
    intr = frames[0].intrinsics
    if args.size and tuple(args.size) != (intr.height, intr.width):
        color, depth, intr = resize_views(color, depth, intr, tuple(args.size))
    return {"color": color, "depth": depth, "poses": torch.stack([f.pose for f in frames]), "intrinsics": intr,
            "name": getattr(ds, "name", path.name)}


def camera_rays(poses: torch.Tensor, k) -> tuple[torch.Tensor, torch.Tensor]:
    """World ray origins and directions ``[N, H, W, 3]``. A direction has camera-frame z = 1, so the ray
    parameter ``t`` is z-depth in metres, the unit of the depth images."""
    v, u = torch.meshgrid(torch.arange(k.height, dtype=torch.float32), torch.arange(k.width, dtype=torch.float32),
                          indexing="ij")
    cam = torch.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, torch.ones_like(u)], -1)  # [H, W, 3]
    dirs = torch.einsum("nij,hwj->nhwi", poses[:, :3, :3], cam)
    return poses[:, None, None, :3, 3].expand_as(dirs), dirs


def scene_box(views: dict, origins, dirs) -> torch.Tensor:
    """``[3, 2]`` box (metres) around the back-projected depth of every frame, trimmed of 0.2 % outliers per
    axis and padded by 5 % + 5 cm (so surfaces seen at grazing angles stay inside)."""
    valid = views["depth"] > 0
    if not valid.any():
        fail("the frames have no valid depth; the scene box comes from depth")
    pts = (origins + dirs * views["depth"][..., None])[valid]
    pts = pts[:: max(1, len(pts) // 200_000)]  # an even subsample is plenty for quantiles (and within their limit)
    lo, hi = torch.quantile(pts, torch.tensor([0.002, 0.998]), dim=0)
    pad = 0.05 * (hi - lo) + 0.05
    return torch.stack([lo - pad, hi + pad], -1)


def ray_bounds(depth, origins, dirs, box) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-ray ``near, far`` ``[N, H, W]``: each image's depth range (0.8x its 0.5 % quantile, 1.2x its 99.5 %
    one), intersected with the box (samples outside it would be wasted). Without depth: the box alone."""
    near = torch.full(depth.shape[:1], 0.05)
    far = torch.full(depth.shape[:1], 1e3)
    for i, d in enumerate(depth):
        d = d[d > 0]
        if len(d) > 100:
            q = torch.quantile(d[:: max(1, len(d) // 100_000)], torch.tensor([0.005, 0.995]))
            near[i], far[i] = max(0.05, 0.8 * float(q[0])), 1.2 * float(q[1])
    safe = torch.where(dirs.abs() > 1e-9, dirs, torch.full_like(dirs, 1e-9))
    t0, t1 = (box[:, 0] - origins) / safe, (box[:, 1] - origins) / safe
    t_in, t_out = torch.minimum(t0, t1).amax(-1), torch.maximum(t0, t1).amin(-1)
    near = torch.maximum(near[:, None, None], t_in)
    far = torch.minimum(far[:, None, None], t_out)
    return near, torch.maximum(far, near + 1e-3)  # a ray missing the box renders the background


def prepare_views(args) -> dict:
    """:func:`load_views` plus every pixel's ray (``origins``, ``dirs``), the scene ``box`` and the per-ray
    ``near`` / ``far`` bounds: all that training and evaluation read."""
    views = load_views(args)
    views["origins"], views["dirs"] = camera_rays(views["poses"], views["intrinsics"])
    views["box"] = scene_box(views, views["origins"], views["dirs"])
    views["near"], views["far"] = ray_bounds(views["depth"], views["origins"], views["dirs"], views["box"])
    return views


# --- model ------------------------------------------------------------------------------------------------------
def field_specs(kind: str, box: torch.Tensor, res: int, extra_rank: int = 0) -> tuple[dict, dict]:
    """tdfields specs of the density and appearance fields: ``res`` samples along the box's longest axis."""
    ext = box[:, 1] - box[:, 0]
    shape = [max(2, round(res * float(e / ext.max()))) for e in ext]
    kinds = ("cp", "six_axis") if kind == "hybrid" else (kind, kind)

    def spec(k, channels):
        out = {"kind": k, "aabb": box.tolist(), "grid_shape": shape, "channels": channels}
        if tdfields.KINDS[k].has_rank:
            out["rank"] = RANKS[k] + extra_rank
        return out

    return spec(kinds[0], DENSITY_CHANNELS), spec(kinds[1], APPEARANCE_CHANNELS)


class RadianceField(torch.nn.Module):
    """``[..., 3]`` world points (metres) -> density ``[...]`` (1/m) and colour ``[..., 3]`` in [0, 1].

    The fields are built from tdfields specs, or given as modules (``density=``, ``appearance=``): anything that
    maps world points to ``[..., out_dim]`` features and has ``out_dim`` and ``contains(points)``, e.g. another
    library's encoding placed in the box (benchmarks/nerf_encodings.py). The heads take the fields' widths. With
    neither, only the heads are built (at the default widths)."""

    def __init__(self, density_spec: dict | None = None, appearance_spec: dict | None = None, *,
                 density: torch.nn.Module | None = None, appearance: torch.nn.Module | None = None):
        super().__init__()
        if density_spec is not None:
            density, appearance = tdfields.build(density_spec), tdfields.build(appearance_spec)
        widths = (DENSITY_CHANNELS, APPEARANCE_CHANNELS)
        if density is not None:
            self.density, self.appearance = density, appearance
            widths = (density.out_dim, appearance.out_dim)
        self.density_head = tdfields.MLPDecoder(widths[0], 1, hidden=16, hidden_layers=1)
        self.color_head = tdfields.MLPDecoder(widths[1], 3, hidden=32, output_activation="sigmoid")

    def forward(self, pts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raw = self.density_head(self.density(pts)).squeeze(-1)
        # a field clamps outside points to its border: zero density there instead of smearing the border out
        sigma = DENSITY_SCALE * F.softplus(raw + DENSITY_SHIFT) * self.density.contains(pts)
        return sigma, self.color_head(self.appearance(pts))


def spec_parameters(spec: dict) -> int:
    """Parameters a spec would hold, from its factor shapes alone (a dense grid at 256^3 is never allocated)."""
    cls = tdfields.KINDS[spec["kind"]]
    probe = cls([[0, 1]] * 3, grid_shape=(2, 2, 2), channels=spec["channels"], rank=spec.get("rank"))
    return sum(math.prod(spec["grid_shape"][a] for a in s.axes) * s.width for s in probe.factor_specs().values())


def fit_budget(kind: str, box: torch.Tensor, budget: int, res: int) -> tuple[int, int]:
    """``(res, extra_rank)`` whose total parameter count (fields + heads) is closest to ``budget``. Kinds with a
    rank keep ``res`` and spend the budget on rank (lowering ``res`` only if rank 1 is already too big); dense
    grids and tri-planes have no rank and spend it on resolution."""
    heads = sum(p.numel() for p in RadianceField().parameters())  # built without fields: the two heads alone

    def total(res, extra):
        return sum(spec_parameters(s) for s in field_specs(kind, box, res, extra)) + heads

    def closer(a, b):  # whether total a is closer to the budget than total b
        return abs(a - budget) < abs(b - budget)

    if kind in ("dense_grid", "triplane"):
        res = 4
        while res < 1024 and closer(total(res + 1, 0), total(res, 0)):
            res += 1
        return res, 0
    extra = 1 - min(s.get("rank", 1 << 30) for s in field_specs(kind, box, res))  # rank 1 for the lowest
    while res > 4 and total(res, extra) > budget:
        res -= 1
    while closer(total(res, extra + 1), total(res, extra)):
        extra += 1
    return res, extra


# --- rendering and training ------------------------------------------------------------------------------------
def render(model, o, d, near, far, samples: int, background: float, jitter: bool):
    """Volume-render rays ``o, d [R, 3]`` between ``near, far [R]`` with ``samples`` stratified samples.

    Returns ``rgb [R, 3]``, expected z-depth ``[R]`` (metres; ``far`` where transparent)."""
    offset = torch.rand(len(o), samples, device=o.device) if jitter else 0.5
    t = near[:, None] + (far - near)[:, None] * (torch.arange(samples, device=o.device) + offset) / samples
    sigma, rgb = model(o[:, None] + t[..., None] * d[:, None])  # [R, S], [R, S, 3]
    delta = ((far - near) / samples * d.norm(dim=-1))[:, None]  # metres along the ray (t is z-depth)
    alpha = 1 - torch.exp(-sigma * delta)
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1 - alpha[:, :-1] + 1e-10], -1), -1)
    w = alpha * trans  # [R, S]
    acc = w.sum(-1)
    color = (w[..., None] * rgb).sum(-2) + (1 - acc)[:, None] * background
    return color, (w * t).sum(-1) + (1 - acc) * far


def train(model, rays: dict, args, label: str, seconds: float | None = None) -> tuple[float, int]:
    """Adam on random batches of ``args.rays`` training rays for ``args.steps`` steps or, with ``seconds``, until
    that much wall time has passed (the rates then decay over the time instead of the steps); returns the seconds
    and the steps trained."""
    fields = [*model.density.parameters(), *model.appearance.parameters()]
    heads = [*model.density_head.parameters(), *model.color_head.parameters()]
    opt = torch.optim.Adam([{"params": fields, "lr": args.lr}, {"params": heads, "lr": args.lr / 4}])
    gen = torch.Generator().manual_seed(args.seed)
    n, t0 = len(rays["o"]), time.perf_counter()

    def progress(step: int) -> float:  # fraction of the run done: of the steps, or of the wall time
        return step / args.steps if seconds is None else min(1.0, (time.perf_counter() - t0) / seconds)

    # TensoRF's schedule: rates decay to 1/10 over the run
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** progress(s))
    bar = tqdm(range(args.steps) if seconds is None else itertools.count(), desc=f"fit {label}", leave=False,
               disable=None)
    done = 0
    for step in bar:
        if seconds is not None and time.perf_counter() - t0 >= seconds:
            break
        idx = torch.randint(n, (args.rays,), generator=gen).to(args.device)
        b = {key: v[idx] for key, v in rays.items()}
        rgb, depth = render(model, b["o"], b["d"], b["near"], b["far"], args.samples, args.background, True)
        mse = F.mse_loss(rgb, b["rgb"])
        loss = mse
        valid = b["depth"] > 0
        if args.depth_weight > 0 and valid.any():  # optional: depth as supervision, not only as bounds
            loss = loss + args.depth_weight * (depth - b["depth"])[valid].abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % 25 == 0 or step == args.steps - 1:
            bar.set_postfix(loss=f"{loss.item():.4f}", psnr=f"{-10 * math.log10(max(mse.item(), 1e-10)):.2f}")
        done += 1
    return time.perf_counter() - t0, done


@torch.no_grad()
def evaluate(model, views: dict, test_ids: list[int], args, out: Path) -> dict:
    """Render the held-out views (midpoint samples), score them with scikit-image, write ``gt | render`` PNGs."""
    (out / "renders").mkdir(parents=True, exist_ok=True)
    psnrs, ssims = [], []
    for i in test_ids:
        o, d, near, far = (views[k][i].reshape(-1, *views[k].shape[3:]).to(args.device)
                           for k in ("origins", "dirs", "near", "far"))
        pred = torch.cat([render(model, *c, args.samples, args.background, False)[0]
                          for c in zip(o.split(4096), d.split(4096), near.split(4096), far.split(4096))])
        pred = pred.clamp(0, 1).reshape(views["color"][i].shape).cpu().numpy()
        gt = views["color"][i].numpy()
        psnrs.append(float(peak_signal_noise_ratio(gt, pred, data_range=1.0)))
        ssims.append(float(structural_similarity(gt, pred, channel_axis=-1, data_range=1.0)))
        side = np.concatenate([gt, pred], axis=1)
        iio.imwrite(out / "renders" / f"view_{i:03d}.png", np.round(side * 255).astype(np.uint8))
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "psnr_per_view": psnrs}


def training_rays(views: dict, device) -> tuple[dict, list[int], list[int]]:
    """The rays of the training images as flat ``[R, ...]`` tensors (``o, d, rgb, depth, near, far``) on
    ``device``, and the training and held-out image indices (every ``HOLD_OUT``-th image is held out)."""
    train_ids = [i for i in range(len(views["color"])) if i % HOLD_OUT]
    test_ids = [i for i in range(len(views["color"])) if i % HOLD_OUT == 0]
    keys = {"o": "origins", "d": "dirs", "rgb": "color", "depth": "depth", "near": "near", "far": "far"}
    rays = {k: views[v][train_ids].reshape(-1, *views[v].shape[3:]).to(device) for k, v in keys.items()}
    return rays, train_ids, test_ids


def run_kind(kind: str, views: dict, args, out: Path) -> dict:
    """Build, train and evaluate one kind; writes ``out/metrics.json`` and ``out/renders``; returns the metrics."""
    torch.manual_seed(args.seed)
    res, extra = fit_budget(kind, views["box"], args.budget, args.resolution) if args.budget else (args.resolution, 0)
    density_spec, appearance_spec = field_specs(kind, views["box"], res, extra)
    model = RadianceField(density_spec, appearance_spec).to(args.device)
    rays, train_ids, test_ids = training_rays(views, args.device)
    seconds, _ = train(model, rays, args, kind)
    metrics = evaluate(model, views, test_ids, args, out)
    from slam.engine.runtime import cpu_name

    rep = tdfields.report(model)
    k = views["intrinsics"]
    metrics = {
        "kind": kind, **{m: metrics[m] for m in ("psnr", "ssim")}, "parameters": rep.total_parameters,
        "field_parameters": rep.field_parameters, "seconds": round(seconds, 2), "steps": args.steps,
        "budget": args.budget, "resolution": res,
        "fields": {name: {"kind": s["kind"], "grid_shape": s["grid_shape"], "channels": s["channels"],
                          "rank": s.get("rank")} for name, s in (("density", density_spec),
                                                                  ("appearance", appearance_spec))},
        "dataset": args.dataset, "data": str(args.data) if args.data else "generated", "scene": views["name"],
        "image_size": [k.height, k.width], "train_images": len(train_ids), "held_out": len(test_ids),
        "scene_box": [[round(v, 3) for v in row] for row in views["box"].tolist()],
        "rays_per_step": args.rays, "samples_per_ray": args.samples, "background": args.background_name,
        "depth_weight": args.depth_weight, "seed": args.seed, "threads": torch.get_num_threads(),
        "device": str(args.device), "psnr_per_view": metrics["psnr_per_view"],
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "torch_version": torch.__version__, "tdfields_version": tdfields.__version__, "cpu": cpu_name(),
        "python": platform.python_version(),
    }
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def table(rows: list[dict]) -> str:
    """Markdown table of the metrics of several kinds."""
    lines = ["| kind | parameters | resolution | ranks (density / appearance) | PSNR (dB) | SSIM | seconds |",
             "|---|---|---|---|---|---|---|"]
    for m in rows:
        ranks = " / ".join(str(m["fields"][f]["rank"] or "-") for f in ("density", "appearance"))
        lines.append(f"| {m['kind']} | {m['parameters']:,} | {m['resolution']} | {ranks} | {m['psnr']:.2f} | "
                     f"{m['ssim']:.3f} | {m['seconds']:.0f} |")
    return "\n".join(lines)


# --- command line ----------------------------------------------------------------------------------------------
def parse_args(argv) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, help="dataset folder (optional with --dataset synthetic: generated)")
    p.add_argument("--dataset", default="synthetic", help=f"one of {', '.join(DATASETS)} (default synthetic)")
    p.add_argument("--kind", default="six_axis", help=f"one of {', '.join(KIND_NAMES)} (default six_axis)")
    p.add_argument("--compare", nargs="+", metavar="KIND", help="fit each kind; write compare.json and a table")
    p.add_argument("--budget", type=int, help="total parameters to match per kind (resolution, then rank)")
    p.add_argument("--resolution", type=int, default=64, help="samples along the longest axis without --budget")
    p.add_argument("--steps", type=int, default=2000, help="Adam steps (default 2000)")
    p.add_argument("--rays", type=int, default=1024, help="rays per step (default 1024)")
    p.add_argument("--samples", type=int, default=64, help="stratified samples per ray (default 64)")
    p.add_argument("--lr", type=float, default=0.02, help="field learning rate; heads take a quarter")
    p.add_argument("--depth-weight", type=float, default=0.0, help="weight of an L1 depth loss (default 0: off)")
    p.add_argument("--background", default="black", help="black or white (default black, see the docstring)")
    p.add_argument("--size", help="HxW: resize images (synthetic: the rendered size, default 60x80)")
    p.add_argument("--frames", type=int, help="use the first N frames (synthetic: frames generated, default 24)")
    p.add_argument("--threads", type=int, help="torch threads (default: torch's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--out", type=Path, default=Path("outputs/fit_radiance_field"))
    args = p.parse_args(argv)
    for kind in args.compare or [args.kind]:
        if kind not in KIND_NAMES:
            fail(f"unknown kind {kind!r}; choose from {', '.join(KIND_NAMES)}")
    if args.dataset not in DATASETS:
        fail(f"unknown dataset {args.dataset!r}; choose from {', '.join(DATASETS)}")
    for name, low in (("steps", 1), ("rays", 1), ("samples", 2), ("resolution", 2), ("budget", 1), ("frames", 2),
                      ("threads", 1)):
        if getattr(args, name) is not None and getattr(args, name) < low:
            fail(f"--{name} must be >= {low}, got {getattr(args, name)}")
    if args.background not in ("white", "black"):
        fail(f"--background must be white or black, got {args.background!r}")
    args.background_name, args.background = args.background, float(args.background == "white")
    if args.size is not None:
        size = tuple(int(v) for v in args.size.lower().split("x") if v.isdigit())
        if len(size) != 2 or min(size) < 8 or args.size.lower().count("x") != 1:
            fail(f"--size must be HxW with both at least 8, e.g. 120x160; got {args.size!r}")
        args.size = size
    try:
        args.device = torch.device(args.device)
    except RuntimeError:
        fail(f"--device must be cpu or cuda[:N], got {args.device!r}")
    if args.device.type == "cuda" and not torch.cuda.is_available():
        fail("--device cuda: no CUDA device is available")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    views = prepare_views(args)
    k = views["intrinsics"]
    print(f"{views['name']}: {len(views['color'])} images {k.height}x{k.width}, every {HOLD_OUT}th held out, "
          f"box {[[round(v, 2) for v in r] for r in views['box'].tolist()]} m")
    if not args.compare:
        m = run_kind(args.kind, views, args, args.out)
        print(f"{m['kind']}: PSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.3f}  parameters {m['parameters']:,}  "
              f"training {m['seconds']:.1f} s  outputs: {args.out}")
        return 0
    if not args.budget:
        print(f"{PROG}: note: no --budget, so the kinds compared differ in size", file=sys.stderr)
    rows = [run_kind(kind, views, args, args.out / kind) for kind in args.compare]
    (args.out / "compare.json").write_text(json.dumps(rows, indent=2) + "\n")
    (args.out / "compare.md").write_text(table(rows) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
