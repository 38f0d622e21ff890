"""CP decomposition: a sum of k rank-one terms, one line factor per axis. O(n)."""

from __future__ import annotations

from tdfields.field import FactorSpec, Field


class CP(Field):
    """``f(p) = sum_{i<k} a_i(x) * b_i(y) * c_i(z)``, each factor a ``C``-vector, ``*`` elementwise.

    Parameters ``k C (n_x + n_y + n_z)``. Shapes: ``[..., 3]`` world metres -> ``[..., C]``.
    Factors ``x [n_x, k*C]``, ``y [n_y, k*C]``, ``z [n_z, k*C]`` (rank-major, channel-minor).
    """

    kind = "cp"
    complexity = "O(n)"
    has_rank = True
    default_init_std = 0.1

    def factor_specs(self):
        w = self.rank * self.channels
        return {"x": FactorSpec((0,), w), "y": FactorSpec((1,), w), "z": FactorSpec((2,), w)}

    def terms(self):
        return [("x", "y", "z")]
