"""tdfields: tensor-decomposition feature fields for PyTorch.

Every field maps ``[..., 3]`` world coordinates in metres to ``[..., C]`` features and reports its size::

    import tdfields
    f = tdfields.SixAxis([[0, 4], [0, 3], [0, 2.5]], cell_size=0.03, channels=32, rank=16)
    feats = f(points)                      # [..., 3] -> [..., 32]
    print(tdfields.report(f))              # kind, grid, rank, parameters, bytes, O(n)

Kinds: :class:`DenseGrid` (O(n^3)), :class:`TriPlane` and :class:`VectorMatrix` (O(n^2)), :class:`CP` and
:class:`SixAxis` (O(n)); compositions :class:`MultiResolution` and :class:`Hybrid`; :func:`build` from configs;
:func:`frozen` for blocks in which the parameters are fixed and fields may cache (tracking, meshing);
:func:`plan` for the :class:`Plan` (program, tensors, coordinates) a query evaluates.
"""

from tdfields._version import __version__
from tdfields.bounds import contains, enlarge_bounds, grid_shape_for
from tdfields.checkpoint import load, load_field, save
from tdfields.config import (
    KINDS,
    FieldConfig,
    HybridConfig,
    MultiResolutionConfig,
    build,
    config_from_dict,
    load_config,
)
from tdfields.cp import CP
from tdfields.decoders import MLPDecoder
from tdfields.dense_grid import DenseGrid
from tdfields.field import FactorSpec, Field, FieldLike, plan
from tdfields.frozen import frozen
from tdfields.hybrid import Hybrid
from tdfields.interpolation import to_grid_coords
from tdfields.multires import MultiResolution
from tdfields.ops import interpolate
from tdfields.program import Plan
from tdfields.report import FieldRow, Report, report
from tdfields.resize import grow, resize
from tdfields.six_axis import SixAxis
from tdfields.step_scale import rate_scales, scaled_param_groups, step_scales
from tdfields.triplane import TriPlane
from tdfields.vector_matrix import VectorMatrix

__all__ = [
    "__version__",
    "Field",
    "FactorSpec",
    "FieldLike",
    "Plan",
    "plan",
    "DenseGrid",
    "TriPlane",
    "VectorMatrix",
    "CP",
    "SixAxis",
    "MultiResolution",
    "Hybrid",
    "MLPDecoder",
    "FieldConfig",
    "MultiResolutionConfig",
    "HybridConfig",
    "KINDS",
    "build",
    "frozen",
    "step_scales",
    "rate_scales",
    "scaled_param_groups",
    "config_from_dict",
    "load_config",
    "report",
    "Report",
    "FieldRow",
    "resize",
    "grow",
    "save",
    "load",
    "load_field",
    "enlarge_bounds",
    "grid_shape_for",
    "contains",
    "interpolate",
    "to_grid_coords",
]
