"""The nerfstudio plugin (tdfields.integrations): the encoding, the methods' training and upsampling in Adam.

Needs nerfstudio, which is no dependency of the project: the module is skipped without it. `.ci/nerfstudio_job.sh`
builds the environment it runs in (docs/nerf.md, "nerfstudio plugin").
"""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import tdfields

pytest.importorskip("nerfstudio", reason="nerfstudio is not installed (the nerfstudio extra; .ci/nerfstudio_job.sh "
                                         "builds an environment with it)")

from tdfields.integrations.nerfstudio import TDFieldsEncoding  # noqa: E402
from tdfields.integrations.nerfstudio_methods import tdfields_hybrid  # noqa: E402

# nerfstudio 1.1.5 on torch 2.13 warns about its own indexing and logging: not ours to fix
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning:nerfstudio.*")

BOX = [[-1.5, 2.5], [-0.5, 1.0], [0.0, 2.0]]
HYBRID = {"kind": "hybrid", "fields": {
    "geometry": {"kind": "cp", "aabb": BOX, "grid_shape": [9, 5, 7], "channels": 2, "rank": 3},
    "appearance": {"kind": "six_axis", "aabb": BOX, "grid_shape": [9, 5, 7], "channels": 4, "rank": 2}}}


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize("input_range", [(-1.0, 1.0), (0.0, 1.0)])
@pytest.mark.parametrize("spec", [
    {"kind": "cp", "aabb": BOX, "grid_shape": [9, 5, 7], "channels": 3, "rank": 4},
    {"kind": "multires", "levels": [{"kind": "triplane", "aabb": BOX, "grid_shape": [4, 3, 3], "channels": 2},
                                    {"kind": "triplane", "aabb": BOX, "grid_shape": [9, 5, 7], "channels": 2}]},
    HYBRID,
], ids=["cp", "multires", "hybrid"])
def test_encoding_is_the_field_on_the_mapped_coordinates(spec, input_range):
    torch.manual_seed(0)
    enc = TDFieldsEncoding(spec, input_range=input_range)
    a, b = input_range
    u = torch.rand(2, 5, 7, 3)  # leading batch dims [2, 5, 7]
    coords = (a + (b - a) * u).requires_grad_(True)
    out = enc(coords)
    width = {"cp": 3, "multires": 4, "hybrid": 6}[spec["kind"]]
    assert enc.get_out_dim() == width and out.shape == (2, 5, 7, width)
    lo, hi = torch.tensor(BOX).T
    world = lo + u * (hi - lo)  # the same points in the field's box
    ref = enc.field(world)
    if isinstance(ref, dict):
        ref = torch.cat([ref["geometry"], ref["appearance"]], dim=-1)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-6)
    out.square().sum().backward()
    assert coords.grad is not None and coords.grad.abs().sum() > 0
    grads = [p.grad for p in enc.parameters()]
    assert grads and all(g is not None and g.abs().sum() > 0 for g in grads)


def test_upsample_keeps_the_optimizer_and_resamples_its_state():
    torch.manual_seed(0)
    enc = TDFieldsEncoding(HYBRID)
    opt = torch.optim.Adam(enc.parameters(), lr=0.01)
    x = torch.rand(256, 3) * 2 - 1
    for _ in range(3):
        opt.zero_grad()
        enc(x).square().sum().backward()
        opt.step()
    before = enc(x).detach()
    line = enc.field["geometry"].factors["x"]
    sq_before = float(opt.state[line]["exp_avg_sq"].mean())
    enc.upsample_grid(17, optimizer=opt)  # the finest longest axis 9 -> 17 samples, the others alike
    assert enc.field["geometry"].grid_shape == (17, 9, 13) == enc.grid_shape
    params = list(enc.parameters())
    assert [p for g in opt.param_groups for p in g["params"]] == params  # the new factors, in the same optimizer
    for p in params:
        state = opt.state[p]
        assert int(state["step"]) == 3  # Adam's step count goes on: no new optimizer
        assert state["exp_avg"].shape == p.shape and state["exp_avg_sq"].shape == p.shape
    # the second moments rescaled to a line of 17 samples instead of 9: (9 / 17)^2 of the resampled values
    ratio = float(opt.state[enc.field["geometry"].factors["x"]]["exp_avg_sq"].mean()) / sq_before
    assert 0.6 * (9 / 17) ** 2 < ratio < 1.4 * (9 / 17) ** 2
    # a resample of a multilinear field at a finer lattice is close to the same function
    assert (enc(x).detach() - before).abs().max() < 0.1 * before.abs().max()
    opt.zero_grad()
    enc(x).square().sum().backward()
    opt.step()
    assert all(int(opt.state[p]["step"]) == 4 for p in params)


def test_upsample_can_reset_the_factors_state_in_the_same_optimizer():
    torch.manual_seed(0)
    enc = TDFieldsEncoding(HYBRID)
    head = torch.nn.Linear(6, 1)
    opt = torch.optim.Adam([*enc.parameters(), *head.parameters()], lr=0.01)
    x = torch.rand(64, 3) * 2 - 1
    for _ in range(2):
        opt.zero_grad()
        head(enc(x)).sum().backward()
        opt.step()
    enc.upsample_grid(17, optimizer=opt, adam_state="reset")
    assert [p for g in opt.param_groups for p in g["params"]] == [*enc.parameters(), *head.parameters()]
    assert all(p not in opt.state for p in enc.parameters())  # Adam starts the factors afresh
    assert all(int(opt.state[p]["step"]) == 2 for p in head.parameters())  # and goes on with the rest
    with pytest.raises(ValueError, match="keep or reset"):
        enc.upsample_grid(17, optimizer=opt, adam_state="drop")


def test_the_colour_head_in_bfloat16_keeps_float32_parameters_names_and_outputs():
    """``head_dtype: bfloat16`` (``autocast_head``): TensoRF's MLP gives float32 colours close to the float32 MLP's
    (bfloat16 keeps 8 bits of mantissa), its gradients reach the float32 parameters, and its parameters keep their
    names (checkpoints load either way)."""
    from nerfstudio.field_components.mlp import MLP

    from tdfields.integrations.nerfstudio_model import autocast_head

    torch.manual_seed(0)
    ref = MLP(in_dim=150, num_layers=2, layer_width=128, out_activation=torch.nn.ReLU())
    ours = copy.deepcopy(ref)
    autocast_head(ours, torch.bfloat16)
    x = torch.rand(4096, 150)
    a, b = ref(x), ours(x)
    assert b.dtype == torch.float32 and a.shape == b.shape
    assert (a - b).abs().max() <= 0.02 * a.abs().max()
    a.sum().backward()
    b.sum().backward()
    assert [n for n, _ in ref.named_parameters()] == [n for n, _ in ours.named_parameters()]
    for (n, p), q in zip(ref.named_parameters(), ours.parameters()):
        assert q.dtype == torch.float32 and q.grad.dtype == torch.float32
        assert torch.allclose(q.grad, p.grad, rtol=0.05, atol=0.02 * float(p.grad.abs().max())), n


@pytest.mark.parametrize("rank, channels, components", [(16, 1, 16), (1, 48, 48)], ids=["density", "appearance"])
def test_tdfields_vm_has_tensorfs_parameter_count(rank, channels, components):
    """``tdfields-vm``'s fields are TensoRF's VM factors: as many parameters as nerfstudio's ``TensorVMEncoding``
    with TensoRF's components (16 density, 48 colour), at 64 samples per axis."""
    from nerfstudio.field_components.encodings import TensorVMEncoding

    ours = TDFieldsEncoding({"kind": "vector_matrix", "aabb": [[-1, 1]] * 3, "grid_shape": [64, 64, 64],
                             "channels": channels, "rank": rank})
    theirs = TensorVMEncoding(resolution=64, num_components=components)
    count = sum(p.numel() for p in ours.parameters())
    assert count == sum(p.numel() for p in theirs.parameters()) == 3 * components * (64 * 64 + 64)


def test_missing_fields_are_refused():
    with pytest.raises(TypeError, match="holds no tdfields.Field"):
        TDFieldsEncoding(torch.nn.Linear(3, 2))
    with pytest.raises(ValueError, match="input_range"):
        TDFieldsEncoding(HYBRID["fields"]["geometry"], input_range=(1.0, 1.0))


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """The synthetic room as a nerfstudio dataset: 16 views of 36x48 (14 training, 2 held out)."""
    from slam.data.synthetic import SynthConfig
    from slam.data.synthetic.nerfstudio_export import export_nerfstudio

    return export_nerfstudio(tmp_path_factory.mktemp("room_ns"),
                             SynthConfig(frames=16, height=36, width=48, loop_frames=64, supersample=1))


STEPS, UPSAMPLE_AT = 60, 30


def hybrid_config(room: Path, out: Path, steps: int, adam_state: str, colour_head: str = "per_sample"):
    """``ns-train tdfields-hybrid``'s config at toy sizes: 256 rays of 48 + 24 samples a step, 12 -> 24 samples per
    axis at step 30 (Adam's state of the factors kept or reset), the colour head per sample or deferred, no viewer,
    no evaluation, a checkpoint at the end."""
    config = copy.deepcopy(tdfields_hybrid.config)
    config.output_dir = out
    config.vis = "tensorboard"  # no viewer server; evaluation is switched off below
    config.machine.device_type = "cpu"
    config.max_num_iterations = steps
    config.steps_per_eval_batch = config.steps_per_eval_image = config.steps_per_eval_all_images = 10**6
    config.steps_per_save = 10**6
    dm = config.pipeline.datamanager
    dm.dataparser.data, dm.dataparser.center_method, dm.dataparser.auto_scale_poses = room, "none", False
    dm.train_num_rays_per_batch = 256
    model = config.pipeline.model
    model.init_resolution, model.final_resolution, model.upsampling_iters = 12, 24, (UPSAMPLE_AT,)
    model.num_uniform_samples, model.num_samples = 48, 24
    model.upsample_adam_state = adam_state
    model.colour_head = colour_head
    config.set_timestamp()
    return config


def train(config) -> tuple:
    """``(trainer, encodings optimizer as set up, colour losses)`` of a run of nerfstudio's own training loop
    (callbacks and upsampling included)."""
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    encodings = trainer.optimizers.optimizers["encodings"]
    losses = []
    train_iteration = trainer.train_iteration

    def recorded(step: int):
        loss, loss_dict, metrics = train_iteration(step)
        losses.append(float(loss_dict["rgb_loss"].detach()))
        return loss, loss_dict, metrics

    trainer.train_iteration = recorded
    trainer.train()
    return trainer, encodings, losses


def assert_optimizer_holds_the_fields(trainer, encodings, steps: int) -> None:
    """The encodings' Adam is ``encodings``, holds the fields' live factors, and has ``steps`` steps on each in its
    state."""
    field = trainer.pipeline.model.field
    assert trainer.optimizers.optimizers["encodings"] is encodings  # never rebuilt
    live = list(field.color_encoding.parameters()) + list(field.density_encoding.parameters())
    assert [id(p) for g in encodings.param_groups for p in g["params"]] == [id(p) for p in live]
    assert [id(p) for p in trainer.optimizers.parameters["encodings"]] == [id(p) for p in live]
    for p in live:
        assert int(encodings.state[p]["step"]) == steps and encodings.state[p]["exp_avg"].shape == p.shape
    assert field.density_encoding.grid_shape == (24, 24, 24) == field.color_encoding.grid_shape


def steps_in_state(adam_state: str, steps: int) -> int:
    """Adam's step count of the factors after ``steps`` steps with one upsample after step ``UPSAMPLE_AT``."""
    return steps if adam_state == "keep" else steps - UPSAMPLE_AT - 1


@pytest.fixture(scope="module", params=[("reset", "per_sample"), ("keep", "per_sample"), ("reset", "deferred")],
                ids=["reset", "keep", "deferred"])
def trained(request, room, tmp_path_factory):
    adam_state, colour_head = request.param
    config = hybrid_config(room, tmp_path_factory.mktemp("ns_out"), STEPS, adam_state, colour_head)
    return (adam_state, *train(config))


def test_tdfields_hybrid_trains_and_upsamples_in_its_optimizer(trained):
    """``ns-train tdfields-hybrid`` through nerfstudio's Trainer: the loss falls, and the upsample at step 30
    resamples the fields inside the same Adam (nerfstudio's TensoRF builds a new one), whose state of the factors
    runs on (keep: step count and moments) or restarts there (reset, the default)."""
    adam_state, trainer, encodings, losses = trained
    assert len(losses) == STEPS
    first, last = sum(losses[:10]) / 10, sum(losses[-10:]) / 10
    print(f"rgb loss {first:.4f} -> {last:.4f}")
    assert last < 0.8 * first, f"the colour loss did not fall: {first:.4f} -> {last:.4f}"
    assert_optimizer_holds_the_fields(trainer, encodings, steps_in_state(adam_state, STEPS))
    field = trainer.pipeline.model.field
    assert isinstance(field.density_encoding.field, tdfields.CP)
    assert isinstance(field.color_encoding.field, tdfields.SixAxis)


def test_resumed_training_steps_the_upsampled_fields(trained, room, tmp_path, monkeypatch):
    """Resuming from the checkpoint: nerfstudio resamples the fields before loading them (new tensors) after the
    optimizer was built; the model hands the optimizer the live factors with the loaded state."""
    adam_state, trainer, _, _ = trained
    # nerfstudio 1.1.5's checkpoints hold numpy scalars (its schedulers' rates), which torch >= 2.6 refuses to load
    # by default: the documented switch back (docs/nerf.md, "nerfstudio plugin")
    monkeypatch.setenv("TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD", "1")
    resumed = hybrid_config(room, tmp_path, 5, adam_state, trainer.pipeline.model.config.colour_head)
    resumed.load_dir = trainer.checkpoint_dir
    trainer2, encodings2, losses2 = train(resumed)
    assert len(losses2) == 5
    assert_optimizer_holds_the_fields(trainer2, encodings2, steps_in_state(adam_state, STEPS) + 5)


class _Constant(torch.nn.Module):
    """An encoding whose features are the same everywhere: ``[..., 3]`` -> ``[..., F]``."""

    def __init__(self, value: torch.Tensor):
        super().__init__()
        self.value = torch.nn.Parameter(value)

    def get_out_dim(self) -> int:
        return self.value.shape[0]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.value.expand(*x.shape[:-1], -1)


def _both_heads(model, rays) -> tuple[dict, dict]:
    outputs = []
    for head in ("per_sample", "deferred"):
        model.config.colour_head = head
        outputs.append(model(rays))  # nerfstudio's Model.forward: the box collider's near / far, then get_outputs
    return outputs[0], outputs[1]


@pytest.fixture
def default_float64():
    """Switches torch's default dtype to float64 when called (nerfstudio's samplers and TensoRF's field allocate
    their buffers in it), and back after the test."""
    dtype = torch.get_default_dtype()
    yield lambda: torch.set_default_dtype(torch.float64)
    torch.set_default_dtype(dtype)


def test_the_deferred_head_is_the_per_sample_head_where_the_features_do_not_vary(trained, default_float64,
                                                                                   monkeypatch):
    """``colour_head: deferred`` decodes the weighted mean of a ray's features once: where every sample has the same
    features, TensoRF's per-sample colours are all that one colour, and the two heads give the same image, depth and
    accumulation (and gradients to the head). Where the features vary (the trained field) the images differ."""
    _, trainer, _, _ = trained
    # in float64, so that the two heads' sums (sum_i w_i dh against A dh, in other orders) agree to round-off
    # that is far below the comparison's tolerance on any machine: in float32 they differed by 2.7e-4 relative
    # on one CI machine
    model = copy.deepcopy(trainer.pipeline.model).eval().double()
    config = model.config.colour_head
    cameras = trainer.pipeline.datamanager.train_dataset.cameras
    rays = cameras.generate_rays(camera_indices=0).flatten()[::7]
    rays = rays._apply_fn_to_fields(lambda t: t.double() if t.is_floating_point() else t)
    default_float64()  # after the cameras (float32) made the rays
    from nerfstudio.utils import colors
    monkeypatch.setattr(colors, "WHITE", colors.WHITE.double())  # TensoRF's background for its masked samples
    # the first rays start outside the box and leave it: the coarse pass sees nothing, no fine query, background
    away = torch.tensor([1.0, 1.0, 1.0]) / 3 ** 0.5
    rays.origins[:5] = 3.0 * away
    rays.directions[:5] = away
    with torch.no_grad():
        varying = _both_heads(model, rays)
    assert (varying[0]["rgb"] - varying[1]["rgb"]).abs().max() > 1e-3
    torch.manual_seed(0)
    model.field.color_encoding = _Constant(torch.randn(model.field.color_encoding.get_out_dim(), dtype=torch.float64))
    # a thinner density, so that rays are partly transparent and the background and the mean's 1 / A matter
    density = model.field.get_density
    model.field.get_density = lambda samples: 0.05 * density(samples)
    ref, ours = _both_heads(model, rays)
    model.config.colour_head = config
    assert ref["rgb"].shape == ours["rgb"].shape == (rays.shape[0], 3)
    assert float(ref["accumulation"][5:].min()) < 0.8
    assert float(ours["accumulation"][:5].abs().max()) == 0.0 and torch.all(ours["rgb"][:5] == 1.0)  # white
    with torch.no_grad():
        empty = _both_heads(model, rays[:5])  # a batch where no ray has a fine query
    assert torch.equal(empty[0]["rgb"], empty[1]["rgb"]) and torch.all(empty[1]["rgb"] == 1.0)
    for key in ("rgb", "accumulation", "depth"):
        assert torch.allclose(ref[key], ours[key], rtol=0, atol=1e-12), key
    head = list(model.field.mlp_head.parameters())
    g_ref = torch.autograd.grad(ref["rgb"].sum(), head)
    g_ours = torch.autograd.grad(ours["rgb"].sum(), head)
    for a, b in zip(g_ref, g_ours):  # sum_i w_i dh against A dh
        assert (a - b).abs().max() <= 1e-10 * a.abs().max(), float((a - b).abs().max() / a.abs().max())


@pytest.mark.parametrize("key, value, message", [
    ("head_dtype", "float16", "head_dtype 'float16': choose float32 or bfloat16"),
    ("colour_head", "per_ray", "colour_head 'per_ray': choose per_sample or deferred"),
    ("use_sh", True, "colour_head deferred runs the MLP head per ray"),
])
def test_unknown_model_options_are_refused_naming_them(room, tmp_path, key, value, message):
    config = hybrid_config(room, tmp_path, 1, "reset", "deferred" if key == "use_sh" else "per_sample")
    setattr(config.pipeline.model, key, value)
    trainer = config.setup(local_rank=0, world_size=1)
    with pytest.raises(ValueError, match=message):
        trainer.setup()


def test_ns_train_finds_the_four_methods():
    """The ``nerfstudio.method_configs`` entry points of pyproject.toml, as ``ns-train`` discovers them (needs the
    package installed after they were added: an older install's metadata lacks them)."""
    from nerfstudio.plugins.registry import discover_methods

    methods, descriptions = discover_methods()
    for name in ("tdfields-cp", "tdfields-six-axis", "tdfields-hybrid", "tdfields-vm"):
        assert methods[name].method_name == name and "tdfields" in descriptions[name]
    assert methods["tdfields-six-axis"].pipeline.model.density_kind == "six_axis"
    vm = methods["tdfields-vm"].pipeline.model
    assert (vm.density_kind, vm.density_rank, vm.appearance_kind, vm.appearance_rank) == (
        "vector_matrix", 16, "vector_matrix", 1)


@pytest.mark.parametrize("module", ["nerfstudio", "nerfstudio_model", "nerfstudio_methods", "nerfstudio_deferred"])
def test_without_nerfstudio_the_import_error_names_the_extra(module):
    """Each module of the plugin, imported where nerfstudio is missing (hidden here in a fresh interpreter)."""
    code = ("import sys; sys.modules['nerfstudio'] = None\n"
            f"import tdfields, tdfields.integrations\nimport tdfields.integrations.{module}")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 1
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("ImportError: tdfields.integrations.nerfstudio needs nerfstudio: pip install "
                           "'tdfields[nerfstudio]'"), last
