"""Tri-plane (ESLAM): three axis-aligned feature planes, summed. O(n^2)."""

from __future__ import annotations

from tdfields.field import FactorSpec, Field


class TriPlane(Field):
    """``f(p) = F_xy(x, y) + F_xz(x, z) + F_yz(y, z)``, bilinear; parameters ``C (n_x n_y + n_x n_z + n_y n_z)``.

    Shapes: ``[..., 3]`` world metres -> ``[..., C]``. Factors ``xy [n_x, n_y, C]``, ``xz [n_x, n_z, C]``,
    ``yz [n_y, n_z, C]``.
    """

    kind = "triplane"
    complexity = "O(n^2)"

    def factor_specs(self):
        c = self.channels
        return {"xy": FactorSpec((0, 1), c), "xz": FactorSpec((0, 2), c), "yz": FactorSpec((1, 2), c)}

    def terms(self):
        return [("xy",), ("xz",), ("yz",)]
