"""Typed SLAM configuration: YAML presets layered base <- representation <- dataset <- scene, plus ``key=value``
overrides.

A preset is a name under ``slam/configs`` (``synthetic``, ``replica/room0``, ``tum/fr1_rpy-cpu`` ...) or a path
to a YAML file. Layering: ``base.yaml`` <- representation block <- the preset's parents <- the preset <- overrides.
A file's parent is its ``inherit`` key when present, else the folder's dataset file (``tum/x`` inherits ``tum``),
else ``base``. The ``representation`` key (``lrslam`` default, ``eslam``, ``cp_cp``, ``sa_sa``, ``sa_cp``,
``vm_sa``: :data:`REPRESENTATIONS`, one per file) picks ``configs/representations/<name>.yaml``, which sets each
quantity's field kind (:data:`FIELD_KINDS`: whatever :data:`tdfields.KINDS` holds) and rank; cell
sizes and channels come from ``base.yaml`` (the same grids for every representation), and any explicit key (a
preset's or an override's) wins.

Every key is checked against the dataclasses below, and every numeric key against its range (``num(...)``): an
unknown key or file, a badly typed or out-of-range value raises :class:`slam.errors.SlamInputError` naming the key,
the value and what is allowed. Defaults are ESLAM's (docs/slam.md, "The pipeline (as implemented)") unless a
key's meaning says "(ours)". Every key with its type, default, range and meaning: docs/configuration.md, written
by :mod:`slam.config.reference`.
"""

from slam.config.load import (
    CONFIG_DIR,
    MOVED,
    config_from_dict,
    list_presets,
    load_config,
    parse_overrides,
    save_config,
)
from slam.config.schema import (
    FIELD_KINDS,
    KEYFRAME_STORAGES,
    MAPPING_WEIGHTS,
    REPRESENTATIONS,
    TRACKING_WEIGHTS,
    Config,
    DataConfig,
    EvaluationConfig,
    FieldSpec,
    LoopsConfig,
    MappingConfig,
    MeshingConfig,
    Range,
    RenderingConfig,
    SceneConfig,
    TrackingConfig,
    choice,
    num,
)

__all__ = [
    "CONFIG_DIR", "MOVED", "config_from_dict", "list_presets", "load_config", "parse_overrides", "save_config",
    "FIELD_KINDS", "KEYFRAME_STORAGES", "MAPPING_WEIGHTS", "REPRESENTATIONS", "TRACKING_WEIGHTS", "Config",
    "DataConfig", "EvaluationConfig", "FieldSpec", "LoopsConfig", "MappingConfig", "MeshingConfig", "Range", "RenderingConfig",
    "SceneConfig", "TrackingConfig", "choice", "num",
]
