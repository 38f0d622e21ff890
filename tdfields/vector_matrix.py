"""Vector-matrix (TensoRF VM): each plane times the line along the remaining axis, rank k. O(n^2)."""

from __future__ import annotations

from tdfields.field import FactorSpec, Field

# (plane axes, line axis) for the three modes
_MODES = {"yz_x": ((1, 2), 0), "xz_y": ((0, 2), 1), "xy_z": ((0, 1), 2)}


class VectorMatrix(Field):
    """``f(p) = sum_i M^yz_i(y, z) * v^x_i(x) + M^xz_i(x, z) * v^y_i(y) + M^xy_i(x, y) * v^z_i(z)``.

    Every factor carries ``C``-vectors; ``*`` is elementwise. Parameters
    ``k C (n_y n_z + n_x + n_x n_z + n_y + n_x n_y + n_z)``.

    Shapes: ``[..., 3]`` world metres -> ``[..., C]``. Factors ``plane_<mode> [n_a, n_b, k*C]`` and
    ``line_<mode> [n_c, k*C]`` (rank-major, channel-minor).
    """

    kind = "vector_matrix"
    complexity = "O(n^2)"
    has_rank = True
    default_init_std = 0.1

    def factor_specs(self):
        w = self.rank * self.channels
        specs = {}
        for mode, (plane, line) in _MODES.items():
            specs[f"plane_{mode}"] = FactorSpec(plane, w)
            specs[f"line_{mode}"] = FactorSpec((line,), w)
        return specs

    def terms(self):
        return [(f"plane_{m}", f"line_{m}") for m in _MODES]
