"""The scene model's sections: ``scene`` (the box and the SDF), ``geometry`` / ``appearance`` (each quantity's field)
and ``rendering`` (the samples along a ray)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import tdfields
from slam.config.declare import COUNT, METRES, POSITIVE, RegistryNames, choice, key, num

#: the field kinds of ``geometry.kind`` / ``appearance.kind``: :data:`tdfields.KINDS`, as registered when read
FIELD_KINDS = RegistryNames(tdfields.KINDS)

_BOX = "[[x0,x1],[y0,y1],[z0,z1]]"


@dataclass
class SceneConfig:
    """The scene box (given, or sized from the first frames' depth, and grown as the camera leaves it: ours,
    slam.engine.growth_policy) and the SDF model."""

    bound: Any = key("auto", "scene box in metres, or `auto` (ours): a cube on the first camera sized from the first "
                             "frames' depth (`bound_auto_*`); ESLAM needs a box per scene", type_name=f"`auto` or {_BOX}")
    marching_cubes_bound: Any = key(None, "box the mesh is extracted in (metres); null: the scene box",
                                    type_name=f"null or {_BOX}")
    bound_dividable: float = num(0.24, **METRES, doc=(
        "the box is enlarged per axis to whole multiples of this (metres), so every coarse cell size dividing it "
        "tiles the box (ESLAM's `bound_dividable`)"))
    bound_auto_frames: int = num(10, **COUNT, doc="(ours) with `bound: auto`: the first frames whose depth sizes it")
    bound_auto_margin: float = num(1.0, lo=0, hi=1000.0, doc=(
        "(ours) with `bound: auto`: metres added to the depth percentile to give the cube's half-size"))
    bound_auto_percentile: float = num(99.0, lo=0, hi=100, lo_open=True, doc=(
        "(ours) with `bound: auto`: the percentile of those frames' valid depth in the cube's half-size; a growth "
        "reads a frame's depth at the same quantile"))
    grow: Any = choice("auto", ("auto", True, False), doc=(
        "(ours) grow the box on the side where a trusted frame's depth nears it: `auto` grows an `auto` box and keeps "
        "a given one; `true` / `false`: always / never (slam/engine/growth_policy.py)"), type_name="`auto` or bool")
    grow_margin: float = num(0.3, lo=0, hi=1000.0, doc=(
        "(ours) metres between a frame's depth and the box that make it grow, by whole coarse cells, until the depth "
        "is this far inside again"))
    grow_max_extent: float = num(20.0, **METRES, doc=(
        "(ours) metres per axis the box never grows past (an event says when it would)"))
    grow_reach: str = choice("depth", ("depth", "box"), doc=(
        "(ours) which depth grows the box: `depth`, every reading; `box`, only readings within the automatic box's "
        "starting half-size of the camera, so a camera turning in place does not grow it and one that moves does "
        "(a given box: every reading)"))
    truncation: float = num(0.06, **METRES, doc=(
        "SDF truncation T (metres): the band `D - T <= z <= D + T` of the SDF losses, and the mesh culling's occlusion "
        "tolerance"))
    learnable_beta: bool = key(True, "optimise beta, the sharpness of the SDF-to-opacity conversion, with the decoders "
                                     "(false: fixed at `beta_init`; the presets of noisy depth)")
    beta_init: float = num(10.0, **POSITIVE, doc="beta's starting (or fixed) value")
    decoder_hidden: int = num(16, lo=1, hi=4096, doc="hidden units per layer of the SDF and colour decoders (two "
                                                     "hidden layers each)")


@dataclass
class FieldSpec:
    """One quantity's field: one level per cell size, each of the same kind, rank and channels, their features
    concatenated for the decoder (slam.model.scene.field_spec)."""

    kind: str = choice("cp", FIELD_KINDS, doc="tdfields field kind (the `representation` block sets it)")
    cell_sizes: list = num(lambda: [0.24, 0.06], **METRES, doc=(
        "cell size of each level in metres, coarse to fine (ESLAM's `planes_res` / LRSLAM's Table 1)"))
    rank: int = num(2, lo=1, hi=4096, doc="rank of a decomposed kind (`cp`, `six_axis`, `vector_matrix`; the "
                                          "representation block sets it); tri-planes and grids ignore it")
    channels: int = num(32, lo=1, hi=4096, doc="feature channels of each level")
    init_std: Optional[float] = num(None, **POSITIVE, doc=(
        "standard deviation of the features' random start; null: the kind's tdfields default"))


@dataclass
class RenderingConfig:
    """The samples along a ray (ESLAM's: stratified over the ray, importance around the measured depth) and what
    each costs."""

    n_stratified: int = num(32, lo=2, hi=4096, doc="samples per ray spread over `[0, 1.2 D]` (D: the measured depth)")
    n_importance: int = num(8, lo=0, hi=4096, doc="samples per ray within `D +- 1.5 T` (T: `scene.truncation`)")
    perturb: bool = key(True, "jitter the samples within their intervals (ESLAM's `perturb`)")
    color_cutoff: float = num(0.0, lo=0, hi=1, hi_open=True, doc=(
        "(ours) samples whose compositing weight is at most this skip the colour query (0: every sample, as ESLAM)"))
    # off by default: 2-6 % off a call alone, no measurable change of the loop's frame time at the Adam budget
    # (docs/slam.md, "The fused render tail"); the realtime profile turns it on
    fused: bool = key(False, (
        "(ours) compositing, the colour sum and the five loss terms as numba kernels on the CPU, Triton kernels on "
        "CUDA with `TDFIELDS_BACKEND=triton` (slam/core/fused_render.py); the same values to a few ulp"))
