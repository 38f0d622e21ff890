"""The ``ns-train`` methods of tdfields, registered in pyproject.toml under ``nerfstudio.method_configs``.

| method | density | appearance |
|---|---|---|
| ``tdfields-cp`` | CP, rank 96, 1 channel | CP, rank 64, 48 channels |
| ``tdfields-six-axis`` | Six-axis, rank 48, 1 channel | Six-axis, rank 32, 48 channels |
| ``tdfields-hybrid`` | CP, rank 96, 1 channel | Six-axis, rank 32, 48 channels (LRSLAM's pairing) |
| ``tdfields-vm`` | VM, rank 16, 1 channel | VM, rank 1, 48 channels (TensoRF's own factors) |

The density and appearance fields of the first three have ``288 n`` and ``9216 n`` parameters for ``n`` samples
per axis (a cube box; 608,256 at n = 64), so those three have equal sizes; ``tdfields-vm`` has nerfstudio's
TensoRF's factors and its parameter count (798,720 at n = 64) on tdfields' kernels.
``--pipeline.model.colour-head deferred`` runs the colour MLP once per ray instead of once per sample
(:mod:`tdfields.integrations.nerfstudio_deferred`; measured in docs/nerf.md).
Everything else is nerfstudio's ``tensorf`` method (optimizers, schedules, upsampling at 2000-7000 steps from 128
to 300 samples, 30000 steps), except: the data parser is nerfstudio's own
format (``transforms.json``), the data manager loads rays in the training process (nerfstudio's TensoRF uses a
second process, which on a CPU-only machine competes with training for the same cores), regularisation is L1 on
the density factors (TV needs nerfstudio's planes) and upsampling keeps the optimizer and its learning-rate
schedule (``--pipeline.model.upsample-adam-state keep`` keeps the factors' Adam state too).

:data:`tensorf_no_lpips` is nerfstudio's ``tensorf`` with LPIPS left out and the same data handling as ours: the
reference for timings. It is not registered; to train it::

    NERFSTUDIO_METHOD_CONFIGS="tensorf-no-lpips=tdfields.integrations.nerfstudio_methods:tensorf_no_lpips" \\
        ns-train tensorf-no-lpips ...
"""

from __future__ import annotations

# first: without nerfstudio its ImportError names the extra to install
from tdfields.integrations.nerfstudio_model import NoLPIPSTensoRFModel, TDFieldsModelConfig  # isort: skip

from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig
from nerfstudio.configs.base_config import ViewerConfig
from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManagerConfig
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.models.base_model import ModelConfig
from nerfstudio.models.tensorf import TensoRFModelConfig
from nerfstudio.pipelines.base_pipeline import VanillaPipelineConfig
from nerfstudio.plugins.types import MethodSpecification

__all__ = ["trainer_config", "tdfields_cp", "tdfields_six_axis", "tdfields_hybrid", "tdfields_vm", "tensorf_no_lpips"]


def trainer_config(method_name: str, model: ModelConfig) -> TrainerConfig:
    """nerfstudio's ``tensorf`` trainer settings around ``model``, with the data handling described above."""
    return TrainerConfig(
        method_name=method_name,
        steps_per_eval_batch=500,
        steps_per_save=2000,
        max_num_iterations=30000,
        mixed_precision=False,
        pipeline=VanillaPipelineConfig(
            datamanager=VanillaDataManagerConfig(dataparser=NerfstudioDataParserConfig(),
                                                 train_num_rays_per_batch=4096, eval_num_rays_per_batch=4096),
            model=model,
        ),
        optimizers={
            "fields": {"optimizer": AdamOptimizerConfig(lr=0.001),
                       "scheduler": ExponentialDecaySchedulerConfig(lr_final=0.0001, max_steps=30000)},
            "encodings": {"optimizer": AdamOptimizerConfig(lr=0.02),
                          "scheduler": ExponentialDecaySchedulerConfig(lr_final=0.002, max_steps=30000)},
            "camera_opt": {"optimizer": AdamOptimizerConfig(lr=1e-4, eps=1e-15),
                           "scheduler": ExponentialDecaySchedulerConfig(lr_final=1e-5, max_steps=5000)},
        },
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15),
        vis="viewer",
    )


def _tdfields_method(name: str, density: tuple[str, int], appearance: tuple[str, int],
                     description: str) -> MethodSpecification:
    model = TDFieldsModelConfig(density_kind=density[0], density_rank=density[1], appearance_kind=appearance[0],
                                appearance_rank=appearance[1], camera_optimizer=CameraOptimizerConfig(mode="off"))
    return MethodSpecification(config=trainer_config(name, model), description=description)


tdfields_cp = _tdfields_method(
    "tdfields-cp", ("cp", 96), ("cp", 64),
    "TensoRF on tdfields CP fields (density and appearance); upsampling in the same optimizer")
tdfields_six_axis = _tdfields_method(
    "tdfields-six-axis", ("six_axis", 48), ("six_axis", 32),
    "TensoRF on tdfields Six-axis fields (density and appearance); upsampling in the same optimizer")
tdfields_hybrid = _tdfields_method(
    "tdfields-hybrid", ("cp", 96), ("six_axis", 32),
    "TensoRF on tdfields CP density + Six-axis appearance (LRSLAM's pairing); upsampling in the same optimizer")
tdfields_vm = _tdfields_method(
    "tdfields-vm", ("vector_matrix", 16), ("vector_matrix", 1),
    "TensoRF's VM factors (and parameter count) on tdfields fields; upsampling in the same optimizer")
tensorf_no_lpips = MethodSpecification(
    config=trainer_config("tensorf-no-lpips", TensoRFModelConfig(
        _target=NoLPIPSTensoRFModel, regularization="tv", camera_optimizer=CameraOptimizerConfig(mode="off"))),
    description="nerfstudio's TensoRF (VM) without LPIPS, with tdfields' methods' data handling (a reference)")
