"""The configuration's schema: every key of a SLAM run as a typed dataclass field, with its default, its range and
its one line of meaning (docs/configuration.md prints them: :mod:`slam.config.reference`).

``num(default, lo=..., hi=..., doc=...)`` declares a numeric key and its allowed values, ``choice(default, options,
doc=...)`` an enumerated one, ``key(default, doc)`` any other (:mod:`slam.config.declare`);
:mod:`slam.config.validate` checks every value as a config is read. A section per module beside this one; the
top-level keys and :class:`Config` here. Defaults are ESLAM's (docs/slam.md, "The pipeline (as implemented)") unless
a key's meaning says "(ours)".
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from slam.config.declare import (BIG, COUNT, FRACTION, METRES, NONNEG, POSITIVE, RATE, Range, RegistryNames, choice,
                                 key, num)
from slam.config.presets import CONFIG_DIR
from slam.config.schema.data import DataConfig
from slam.config.schema.loops import LoopsConfig
from slam.config.schema.mapping import KEYFRAME_STORAGES, MappingConfig
from slam.config.schema.output import EvaluationConfig, MeshingConfig
from slam.config.schema.scene import FIELD_KINDS, FieldSpec, RenderingConfig, SceneConfig
from slam.config.schema.tracking import TrackingConfig
from slam.config.schema.weights import MAPPING_WEIGHTS, TRACKING_WEIGHTS
from slam.core.losses import LossWeights

# the declaration helpers and the sections are importable from here too (they were defined here)
__all__ = ["BIG", "COUNT", "FRACTION", "FIELD_KINDS", "KEYFRAME_STORAGES", "MAPPING_WEIGHTS", "METRES", "NONNEG",
           "POSITIVE", "RATE", "REPRESENTATIONS", "SECTION_RANGES", "TRACKING_WEIGHTS", "Config", "DataConfig",
           "EvaluationConfig", "FieldSpec", "LoopsConfig", "MappingConfig", "MeshingConfig", "Range", "RegistryNames",
           "RenderingConfig", "SceneConfig", "TrackingConfig", "choice", "key", "num"]


#: the representation blocks, one per ``slam/configs/representations/<name>.yaml``: the default first, then sorted
REPRESENTATIONS = ("lrslam", *sorted(p.stem for p in (CONFIG_DIR / "representations").glob("*.yaml")
                                     if p.stem != "lrslam"))
#: the range of every key of a section class defined outside the schema (its fields cannot declare one)
SECTION_RANGES = {LossWeights: Range(**NONNEG)}


@dataclass
class Config:
    """The resolved configuration (written as ``config.yaml`` next to a run's outputs)."""

    name: str = key("custom", "the run's name: the preset's (a YAML file's stem) unless set; the default output "
                              "folder is `runs/<name>-<representation>`")
    profile: str = key("", "the budget the config was read with (`realtime`, `quality`, `paper` or a YAML file's "
                           "path): a record, its keys are already in the config; `profile=NAME` among the overrides "
                           "chooses it as `--profile` does")
    seed: int = num(0, lo=0, hi=2**32 - 1 - 7919, doc=(
        "seeds torch, numpy, the tracker's pixel draws and the evaluation's samples; the mapper draws from seed + 7919 "
        "(numpy seeds are 32-bit: hence the bound)"))
    device: str = key("cpu", "torch device: `cpu`, `cuda` or `cuda:N` (`--device`); it picks the default profile: "
                             "realtime on the CPU, paper on CUDA")
    threads: int = num(0, lo=0, hi=1024, doc="(ours) torch intra-op threads, the mapping process's and `lrslam "
                                             "mesh`'s too; 0: torch's default")
    keep_freed_memory: bool = key(True, "(ours) glibc: reuse freed big tensors' memory instead of faulting in fresh "
                                        "pages (slam/engine/runtime.py)")
    trim_memory_every: int = num(20, **NONNEG, doc=(
        "(ours) frames between returns of the heap's free pages to the system (bounds memory on long runs); 0: never"))
    parallel: bool = key(False, "(ours) map beside the tracker, which runs up to max(`mapping.every_frame`, 2) frames "
                                "ahead against the previous map (slam/engine/map_worker.py); false: ESLAM's "
                                "sequential order")
    mapper_process: bool = key(False, "(ours) with `parallel`: the mapping calls in a child process instead of a thread "
                                      "(slam/engine/map_process.py): the same results, no shared interpreter lock")
    preload_kernels: bool = key(True, "(ours) load the fused kernels before the first frame by a throwaway mapping and "
                                      "tracking call (slam/engine/rehearsal.py): the same results, the time reported "
                                      "as `preload_s` instead of in the first frames")
    checkpoint_every: int = num(0, **NONNEG, doc="(ours) frames between checkpoints; 0: by time, "
                                                 "`checkpoint_interval_s`")
    checkpoint_interval_s: float = num(60.0, **POSITIVE, doc=(
        "(ours) with `checkpoint_every: 0`: seconds between checkpoints, at most this much work is lost"))
    representation: str = choice("lrslam", REPRESENTATIONS, doc=(
        "the block of slam/configs/representations/ that sets the fields' kinds and ranks: `lrslam` (CP geometry, "
        "Six-axis appearance), `eslam` (tri-planes), the ablations; a given `geometry.*` / `appearance.*` key wins"))
    data: DataConfig = key(DataConfig, "The sequence a run reads, and how its frames are read.")
    scene: SceneConfig = key(SceneConfig, "The scene box and the SDF model.")
    geometry: FieldSpec = key(FieldSpec, "The geometry's (SDF's) field: the representation block sets its kind and "
                                         "rank, base.yaml its cells and channels.")
    appearance: FieldSpec = key(lambda: FieldSpec(kind="six_axis", cell_sizes=[0.24, 0.03], rank=16, channels=32),
                                "The appearance's (colour's) field, set as the geometry's.")
    rendering: RenderingConfig = key(RenderingConfig, "The samples along a ray and what each costs.")
    tracking: TrackingConfig = key(TrackingConfig, "Each frame's camera pose: the optimiser, its start, the checks on "
                                                   "its result and the recovery of a lost camera.")
    mapping: MappingConfig = key(MappingConfig, "The map's optimisation: which frames are mapped, each call's keyframe "
                                                "window and optimiser, and the keyframe store.")
    loops: LoopsConfig = key(LoopsConfig, "Loop closure: place recognition, verification and a pose graph over "
                                          "keyframes.")
    meshing: MeshingConfig = key(MeshingConfig, "The mesh extracted at the end of a run (and by `lrslam mesh`).")
    evaluation: EvaluationConfig = key(EvaluationConfig, "Reconstruction metrics against a ground-truth mesh.")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
