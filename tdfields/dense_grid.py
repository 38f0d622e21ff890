"""Dense voxel grid (NICE-SLAM-like): one ``n_x * n_y * n_z * C`` volume, trilinear. O(n^3)."""

from __future__ import annotations

from tdfields.field import FactorSpec, Field


class DenseGrid(Field):
    """``f(p) = trilinear(V)(p)``; parameters ``C * n_x * n_y * n_z``.

    Shapes: ``[..., 3]`` world metres -> ``[..., C]``. Factor ``volume``: ``[n_x, n_y, n_z, C]``.
    """

    kind = "dense_grid"
    complexity = "O(n^3)"

    def factor_specs(self):
        return {"volume": FactorSpec((0, 1, 2), self.channels)}

    def terms(self):
        return [("volume",)]
