"""Where a TensoRF training step's time goes (issue 23): the whole step of ``tdfields-hybrid`` and of nerfstudio's
TensoRF VM (``tensorf-no-lpips``), and TensoRF's colour head alone, interleaved, one thread.

Both models are built by nerfstudio's own Trainer on the synthetic room exported as a nerfstudio dataset (written
to ``--room`` if it is not there), at the settings of docs/nerf.md's table: 1,024 rays a step, 64 uniform + 32
importance samples a ray, 64 samples per axis. A step is ``pipeline.get_train_loss_dict`` and the backward of its
loss (no optimizer step, so every repeat sees the same model). The head is what both models run on the 1,024 x 32
importance samples: the appearance features' linear map to 27, their and the view direction's frequency encodings,
the two-layer 128-wide MLP and the RGB output, forward and backward. If the head alone takes a third of TensoRF's
step, no encoding makes the whole model three times faster than TensoRF at these settings. Both are also timed with
the MLP in bfloat16 (``--pipeline.model.head-dtype bfloat16``, ``autocast_head``).

Needs nerfstudio (``.ci/nerfstudio_job.sh VENV`` builds an environment with it)::

    OMP_NUM_THREADS=1 VENV/bin/python benchmarks/nerf_step_split.py --out benchmarks/results/nerf_step_split.json
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _pipeline(spec, room: Path, out: Path, **model):
    config = copy.deepcopy(spec.config)
    config.output_dir, config.vis, config.machine.device_type = out, "tensorboard", "cpu"
    dm = config.pipeline.datamanager
    dm.dataparser.data, dm.dataparser.center_method, dm.dataparser.auto_scale_poses = room, "none", False
    dm.train_num_rays_per_batch = 1024
    m = config.pipeline.model
    m.init_resolution, m.final_resolution, m.upsampling_iters = 64, 64, ()
    m.num_uniform_samples, m.num_samples = 64, 32
    for key, value in model.items():
        setattr(m, key, value)
    config.set_timestamp()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer.pipeline


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--room", default="/tmp/nerf_step_split_room", help="nerfstudio dataset folder (written if absent)")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)

    import torch

    from _nerf_room import ensure_room
    from _stamp import write_timings
    from tdfields.integrations.nerfstudio_methods import tdfields_hybrid, tensorf_no_lpips
    from tdfields.integrations.nerfstudio_model import autocast_head

    torch.set_num_threads(1)
    room = ensure_room(Path(args.room))
    scratch = Path(tempfile.mkdtemp())
    pipes = {"tdfields-hybrid step": _pipeline(tdfields_hybrid, room, scratch / "a"),
             "tdfields-hybrid step, head bfloat16": _pipeline(tdfields_hybrid, room, scratch / "c",
                                                              head_dtype="bfloat16"),
             "tensorf-no-lpips step": _pipeline(tensorf_no_lpips, room, scratch / "b")}

    def step(pipe):
        t0 = time.perf_counter()
        _, losses, _ = pipe.get_train_loss_dict(0)
        sum(losses.values()).backward()
        pipe.model.zero_grad(set_to_none=True)
        return time.perf_counter() - t0

    field = pipes["tensorf-no-lpips step"].model.field
    n = 1024 * 32
    feats = torch.rand(n, field.B.in_features, requires_grad=True)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3), dim=-1)

    bf16_mlp = copy.deepcopy(field.mlp_head)
    autocast_head(bf16_mlp, torch.bfloat16)

    def head(mlp):
        t0 = time.perf_counter()
        f = field.B(feats)
        x = torch.cat([f, dirs, field.feature_encoding(f), field.direction_encoding(dirs)], dim=-1)
        field.field_output_rgb(mlp(x)).sum().backward()
        field.zero_grad(set_to_none=True)
        mlp.zero_grad(set_to_none=True)
        return time.perf_counter() - t0

    calls = {**{k: (lambda p=p: step(p)) for k, p in pipes.items()},
             "colour head alone": lambda: head(field.mlp_head), "colour head alone, bfloat16": lambda: head(bf16_mlp)}
    for fn in calls.values():  # warm-up: kernels compiled, caches filled
        fn(), fn()
    times = {k: [] for k in calls}
    for _ in range(args.repeats):
        for k, fn in calls.items():
            times[k].append(fn())
    res = write_timings(args.out, times, "", rays=1024, samples="64 uniform + 32 importance", resolution=64)
    med = res["median_s"]
    tensorf = med["tensorf-no-lpips step"]
    for k, v in med.items():
        print(f"{k} / tensorf step: {v / tensorf:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
