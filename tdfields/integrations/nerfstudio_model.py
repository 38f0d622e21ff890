"""TensoRF-style nerfstudio models whose density and appearance encodings are tdfields fields.

:class:`TDFieldsModel` is nerfstudio's TensoRF (its field, samplers, renderers, losses and upsampling schedule)
with two changes: the encodings are :class:`~tdfields.integrations.nerfstudio.TDFieldsEncoding` of any kinds, and
an upsample resamples the factors *and Adam's state* in place with :func:`tdfields.resize`, where nerfstudio's
TensoRF throws its ``encodings`` optimizer away and builds a new one (moments and step count lost).

:class:`NoLPIPSTensoRFModel` is nerfstudio's TensoRF unchanged except that it builds no LPIPS metric: torchmetrics'
LPIPS needs torchvision and downloads network weights, neither of which works offline beside a CPU-only torch.
Its evaluation reports PSNR and SSIM (``pytorch_msssim``, which nerfstudio already requires). It is the
reference ``ns-train tensorf`` model of docs/nerf.md, "nerfstudio plugin", and the base of :class:`TDFieldsModel`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Type

import torch

# first: without nerfstudio its ImportError names the extra to install
from tdfields.integrations.nerfstudio import TDFieldsEncoding  # isort: skip
from tdfields.integrations.nerfstudio_deferred import deferred_outputs  # isort: skip

from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.field_components.encodings import NeRFEncoding, TensorCPEncoding, TensorVMEncoding, TriplaneEncoding
from nerfstudio.fields.tensorf_field import TensoRFField
from nerfstudio.model_components.losses import MSELoss
from nerfstudio.model_components.ray_samplers import PDFSampler, UniformSampler
from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer, RGBRenderer
from nerfstudio.model_components.scene_colliders import AABBBoxCollider
from nerfstudio.models.base_model import Model
from nerfstudio.models.tensorf import TensoRFModel, TensoRFModelConfig
from nerfstudio.utils import colormaps
from pytorch_msssim import ssim
from torch import nn

import tdfields

__all__ = ["NoLPIPSTensoRFModel", "TDFieldsModel", "TDFieldsModelConfig", "adopt_parameters", "autocast_head",
           "shape_for", "psnr"]


def shape_for(aabb: torch.Tensor, resolution: int) -> list[int]:
    """Samples per axis of a ``(3, 2)`` box: ``resolution`` along its longest axis, the others in proportion (a
    cube gets ``resolution`` on every axis, as nerfstudio's TensoRF encodings have)."""
    ext = aabb[:, 1] - aabb[:, 0]
    return [max(2, round(resolution * float(e / ext.max()))) for e in ext]


def psnr(image: torch.Tensor, rgb: torch.Tensor) -> float:
    """PSNR in dB of ``rgb`` against ``image`` (same shapes, values in [0, 1])."""
    return float(-10.0 * torch.log10(torch.mean((image - rgb) ** 2).clamp_min(1e-10)))


def adopt_parameters(optimizer: torch.optim.Optimizer, live: List[torch.nn.Parameter]) -> None:
    """Make ``optimizer``, built over one list of parameters, hold ``live`` instead: the same parameters in the
    same order, possibly replaced by new tensors (a resize). Each old parameter's state moves to its successor."""
    held = [p for group in optimizer.param_groups for p in group["params"]]
    if [id(p) for p in held] == [id(p) for p in live]:
        return
    if len(optimizer.param_groups) != 1 or len(held) != len(live):
        raise RuntimeError(f"the encodings optimizer holds {len(held)} parameters in {len(optimizer.param_groups)} "
                           f"groups, the model {len(live)}: cannot match them")
    for old, new in zip(held, live):
        if old in optimizer.state:
            optimizer.state[new] = optimizer.state.pop(old)
    optimizer.param_groups[0]["params"] = list(live)


def autocast_head(module: nn.Module, dtype: torch.dtype) -> None:
    """Run ``module`` (the colour MLP) under :func:`torch.autocast` in ``dtype`` on its input's device, returning
    float32: its matrix products run in ``dtype`` while its parameters, their gradients and Adam stay float32 (the
    forward is wrapped on the instance, so parameter names and checkpoints do not change)."""
    inner = module.forward

    def forward(x: torch.Tensor) -> torch.Tensor:
        with torch.autocast(x.device.type, dtype=dtype):
            out = inner(x)
        return out.float()

    module.forward = forward


class NoLPIPSTensoRFModel(TensoRFModel):
    """nerfstudio's TensoRF without LPIPS; :meth:`build_encodings` is the one place subclasses change."""

    def build_encodings(self) -> Tuple[nn.Module, nn.Module]:
        """``(density, colour)`` encodings, each taking ``[..., 3]`` in [-1, 1]: nerfstudio's, as TensoRF builds
        them for ``config.tensorf_encoding``."""
        kinds = {"vm": TensorVMEncoding, "cp": TensorCPEncoding, "triplane": TriplaneEncoding}
        if self.config.tensorf_encoding not in kinds:
            raise ValueError(f"Encoding {self.config.tensorf_encoding} not supported")
        cls = kinds[self.config.tensorf_encoding]
        return (cls(resolution=self.init_resolution, num_components=self.num_den_components),
                cls(resolution=self.init_resolution, num_components=self.num_color_components))

    def head_options(self) -> Dict[str, int | bool]:
        """The colour head's arguments of ``TensoRFField``: TensoRF's two-layer MLP of width 128."""
        return {"head_mlp_num_layers": 2, "head_mlp_layer_width": 128, "use_sh": False}

    def populate_modules(self) -> None:
        """TensoRF's modules, built as ``TensoRFModel.populate_modules`` builds them, less its metrics: that method
        constructs torchmetrics' LPIPS, which cannot be built offline, so it is not called."""
        Model.populate_modules(self)  # nerfstudio's base: the near/far collider
        density_encoding, color_encoding = self.build_encodings()
        self.field = TensoRFField(
            self.scene_box.aabb,
            feature_encoding=NeRFEncoding(in_dim=self.appearance_dim, num_frequencies=2, min_freq_exp=0,
                                          max_freq_exp=2),
            direction_encoding=NeRFEncoding(in_dim=3, num_frequencies=2, min_freq_exp=0, max_freq_exp=2),
            density_encoding=density_encoding,
            color_encoding=color_encoding,
            appearance_dim=self.appearance_dim,
            **self.head_options(),
        )
        self.sampler_uniform = UniformSampler(num_samples=self.config.num_uniform_samples, single_jitter=True)
        self.sampler_pdf = PDFSampler(num_samples=self.config.num_samples, single_jitter=True, include_original=False)
        self.renderer_rgb = RGBRenderer(background_color=self.config.background_color)
        self.renderer_accumulation = AccumulationRenderer()
        self.renderer_depth = DepthRenderer()
        self.rgb_loss = MSELoss()
        if self.config.enable_collider:
            self.collider = AABBBoxCollider(scene_box=self.scene_box)
        if self.config.tensorf_encoding == "cp" and self.config.regularization == "tv":
            raise RuntimeError("TV reg not supported for CP decomposition")
        self.camera_optimizer = self.config.camera_optimizer.setup(num_cameras=self.num_train_data, device="cpu")

    def get_image_metrics_and_images(
        self, outputs: Dict[str, torch.Tensor], batch: Dict[str, torch.Tensor]
    ) -> Tuple[Dict[str, float], Dict[str, torch.Tensor]]:
        """TensoRF's evaluation of one image, ``[H, W, 3]`` in [0, 1]: PSNR (dB) and SSIM, no LPIPS."""
        image = self.renderer_rgb.blend_background(batch["image"].to(outputs["rgb"].device))
        rgb = outputs["rgb"]
        acc = colormaps.apply_colormap(outputs["accumulation"])
        assert self.config.collider_params is not None
        depth = colormaps.apply_depth_colormap(outputs["depth"], accumulation=outputs["accumulation"],
                                               near_plane=self.config.collider_params["near_plane"],
                                               far_plane=self.config.collider_params["far_plane"])
        combined_rgb = torch.cat([image, rgb], dim=1)
        # [H, W, C] -> [1, C, H, W] for SSIM
        nchw = [torch.moveaxis(x, -1, 0)[None].float() for x in (image, rgb)]
        metrics = {"psnr": psnr(image, rgb), "ssim": float(ssim(nchw[0], nchw[1], data_range=1.0))}
        self.camera_optimizer.get_metrics_dict(metrics)
        return metrics, {"img": combined_rgb, "accumulation": acc, "depth": depth}


@dataclass
class TDFieldsModelConfig(TensoRFModelConfig):
    """TensoRF on tdfields encodings. ``init_resolution`` / ``final_resolution`` are samples along the scene box's
    longest axis (every axis of nerfstudio's cube box); ``num_den_components`` / ``num_color_components`` and
    ``tensorf_encoding`` are not used (the fields below replace them)."""

    _target: Type = field(default_factory=lambda: TDFieldsModel)
    density_kind: str = "cp"
    """tdfields kind of the density field: cp, six_axis, vector_matrix, triplane or dense_grid"""
    density_rank: int = 96
    """rank of the density field (kinds with a rank)"""
    density_channels: int = 1
    """density features, summed into the density as TensoRF sums its components"""
    appearance_kind: str = "six_axis"
    """tdfields kind of the appearance field"""
    appearance_rank: int = 32
    """rank of the appearance field (kinds with a rank)"""
    appearance_channels: int = 48
    """appearance features (TensoRF's colour components), mapped to appearance_dim by a linear layer"""
    init_std: Optional[float] = None
    """initial factor standard deviation of both fields (None: each kind's default)"""
    regularization: str = "l1"
    """none or l1 (an L1 penalty on the density factors); TV needs nerfstudio's planes"""
    head_mlp_layer_width: int = 128
    """width of the colour MLP's two layers (TensoRF's: 128)"""
    use_sh: bool = False
    """decode colour with spherical harmonics of sh_levels bands instead of the MLP (no view-dependent MLP)"""
    sh_levels: int = 2
    """spherical-harmonic bands with use_sh"""
    head_dtype: str = "float32"
    """float32, or bfloat16: the colour MLP's two layers under torch.autocast (a third of TensoRF's step is that MLP;
    bfloat16 matrix products are ~3x faster on CPUs with AMX, slower on CPUs without bfloat16 units)"""
    colour_head: str = "per_sample"
    """per_sample (TensoRF: the MLP colours every fine sample, the colours are composited) or deferred (the
    appearance features are composited and the MLP runs once per ray: tdfields.integrations.nerfstudio_deferred)"""
    upsample_adam_state: str = "reset"
    """at an upsample, Adam's state of the factors is reset (fresh moments, as nerfstudio's new optimizer has) or
    keep (resampled and rescaled, step count kept); the optimizer itself is kept either way"""


class TDFieldsModel(NoLPIPSTensoRFModel):
    """TensoRF with tdfields encodings; upsampling keeps the ``encodings`` optimizer and its schedule."""

    config: TDFieldsModelConfig

    def populate_modules(self) -> None:
        """TensoRF's modules (:meth:`NoLPIPSTensoRFModel.populate_modules`), the colour MLP in ``head_dtype``."""
        super().populate_modules()
        if self.config.head_dtype != "float32" and not self.config.use_sh:
            autocast_head(self.field.mlp_head, getattr(torch, self.config.head_dtype))

    def get_outputs(self, ray_bundle):
        """TensoRF's outputs for ``R`` rays (``rgb [R, 3]``, ``accumulation [R, 1]``, ``depth [R, 1]``), the colour
        head per sample or, with ``colour_head: deferred``, per ray (``nerfstudio_deferred.deferred_outputs``)."""
        if self.config.colour_head == "deferred":
            return deferred_outputs(self, ray_bundle)
        return super().get_outputs(ray_bundle)

    def field_spec(self, which: str) -> dict:
        """The tdfields spec of the ``density`` or ``appearance`` field: the scene box, ``init_resolution``."""
        kind = getattr(self.config, f"{which}_kind")
        if kind not in tdfields.KINDS:
            raise ValueError(f"{which}_kind {kind!r}: choose one of {', '.join(sorted(tdfields.KINDS))}")
        aabb = self.scene_box.aabb.T.float()  # nerfstudio's [2, 3] (min row, max row) -> tdfields' (3, 2)
        spec = {"kind": kind, "aabb": aabb.tolist(), "grid_shape": shape_for(aabb, self.init_resolution),
                "channels": getattr(self.config, f"{which}_channels"), "init_std": self.config.init_std}
        if tdfields.KINDS[kind].has_rank:
            spec["rank"] = getattr(self.config, f"{which}_rank")
        return spec

    def head_options(self) -> Dict[str, int | bool]:
        """The colour head from the config (TensoRF's by default)."""
        return {"head_mlp_num_layers": 2, "head_mlp_layer_width": self.config.head_mlp_layer_width,
                "use_sh": self.config.use_sh, "sh_levels": self.config.sh_levels}

    def build_encodings(self) -> Tuple[nn.Module, nn.Module]:
        """Two :class:`TDFieldsEncoding` in the scene box, taking TensoRF's [-1, 1] coordinates."""
        if self.config.upsample_adam_state not in ("keep", "reset"):
            raise ValueError(f"upsample_adam_state {self.config.upsample_adam_state!r}: choose keep or reset")
        if self.config.head_dtype not in ("float32", "bfloat16"):
            raise ValueError(f"head_dtype {self.config.head_dtype!r}: choose float32 or bfloat16")
        if self.config.colour_head not in ("per_sample", "deferred"):
            raise ValueError(f"colour_head {self.config.colour_head!r}: choose per_sample or deferred")
        if self.config.colour_head == "deferred" and (self.config.use_sh or self.config.use_gradient_scaling):
            raise ValueError("colour_head deferred runs the MLP head per ray: it takes neither use_sh nor "
                             "use_gradient_scaling")
        if self.config.regularization not in ("none", "l1"):
            raise ValueError(f"regularization {self.config.regularization!r}: tdfields models take none or l1")
        return TDFieldsEncoding(self.field_spec("density")), TDFieldsEncoding(self.field_spec("appearance"))

    def upsample(self, resolution: int, optimizer: Optional[torch.optim.Optimizer] = None) -> None:
        """Resample both encodings to ``resolution`` samples along the longest axis, in ``optimizer`` (its state of
        the factors kept or reset as ``config.upsample_adam_state`` says)."""
        for encoding in (self.field.density_encoding, self.field.color_encoding):
            encoding.upsample_grid(resolution, optimizer=optimizer, adam_state=self.config.upsample_adam_state)

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> List[TrainingCallback]:
        """Upsample at ``upsampling_iters`` to TensoRF's resolutions, in the existing optimizer (nerfstudio's
        TensoRF builds a new ``encodings`` optimizer and learning-rate schedule there)."""
        optimizers = training_callback_attributes.optimizers
        assert optimizers is not None
        # nerfstudio calls this after loading a checkpoint, whose update_to_step resampled the fields into new
        # parameters while the optimizer (built before) kept the old ones, with the loaded state on them
        adopt_parameters(optimizers.optimizers["encodings"], self.get_param_groups()["encodings"])
        optimizers.parameters["encodings"] = self.get_param_groups()["encodings"]

        def upsample(step: int) -> None:
            resolution = self.upsampling_steps[list(self.upsampling_iters).index(step)]
            self.upsample(resolution, optimizers.optimizers["encodings"])
            # nerfstudio clips gradients over this list (when max_norm is set): keep it the live parameters
            optimizers.parameters["encodings"] = self.get_param_groups()["encodings"]

        return [TrainingCallback(where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
                                 iters=tuple(self.upsampling_iters), func=upsample)]
