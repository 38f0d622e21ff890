"""Six-axis (LRSLAM Eq. 3): each tri-plane plane replaced by its own rank-k CP factorisation. O(n)."""

from __future__ import annotations

from typing import ClassVar

import torch
from einops import rearrange, reduce

from tdfields.field import FactorSpec, Field
from tdfields.interpolation import interpolate

# plane name -> (first axis, second axis); factor names are f"{plane}_{axis letter}"
_PLANES = {"xy": (0, 1), "yz": (1, 2), "zx": (2, 0)}
_AXIS = "xyz"


class SixAxis(Field):
    """``f(p) = sum_i u_i(x) v_i(y) + sum_i p_i(y) q_i(z) + sum_i r_i(z) s_i(x)``, ``C``-vectors, rank ``k``.

    Parameters ``2 k C (n_x + n_y + n_z)``. Shapes: ``[..., 3]`` world metres -> ``[..., C]``.
    Factors ``xy_x [n_x, k*C]``, ``xy_y [n_y, k*C]``, ``yz_y``, ``yz_z``, ``zx_z``, ``zx_x`` (rank-major).

    Two exact evaluation strategies, chosen per call by ``strategy``:

    * ``"factors"``: interpolate the six line factors at every point and multiply. Memory ``O(N k C)`` for N
      points and ``O(n)`` in the grid: the strategy whose memory grows linearly with the scene.
    * ``"planes"``: first compose the three rank-k planes ``P_xy[x, y] = sum_i u_i[x] v_i[y]`` (a batched matmul,
      ``O(k C n^2)`` flops) and then interpolate them bilinearly. Bilinear interpolation of a separable product
      equals the product of the linear interpolations, so the result is the same up to float rounding, while the
      per-point work drops ``4k``-fold (one 32-wide gather per corner instead of ``k*C``-wide gathers per factor).
      The composed planes are temporaries of size ``C (n_x n_y + n_y n_z + n_z n_x)``.
    * ``"auto"`` (default) composes when those temporaries are smaller than the per-point intermediates of the
      factor path (``N k C`` per factor), i.e. for tracking/mapping-sized batches on room-sized scenes.
    """

    kind = "six_axis"
    complexity = "O(n)"
    has_rank = True
    default_init_std = 0.1
    strategies: ClassVar[tuple[str, ...]] = ("auto", "factors", "planes")

    def __init__(self, *args, strategy: str = "auto", **kwargs):
        super().__init__(*args, **kwargs)
        if strategy not in self.strategies:
            raise ValueError(f"SixAxis: strategy must be one of {self.strategies}, got {strategy!r}")
        self.strategy = strategy

    def factor_specs(self):
        w = self.rank * self.channels
        return {f"{plane}_{_AXIS[a]}": FactorSpec((a,), w) for plane, axes in _PLANES.items() for a in axes}

    def combine(self, samples):
        total = sum(samples[f"{plane}_{_AXIS[a]}"] * samples[f"{plane}_{_AXIS[b]}"] for plane, (a, b) in _PLANES.items())
        return reduce(total, "n (k c) -> n c", "sum", k=self.rank)

    def composed_plane(self, plane: str) -> torch.Tensor:
        """The rank-k plane ``P[a, b, c] = sum_i U[a, i, c] V[b, i, c]`` as ``[n_a, n_b, C]`` (differentiable)."""
        a, b = _PLANES[plane]
        u = rearrange(self.factors[f"{plane}_{_AXIS[a]}"], "n (k c) -> c n k", k=self.rank)
        v = rearrange(self.factors[f"{plane}_{_AXIS[b]}"], "n (k c) -> c k n", k=self.rank)
        return rearrange(torch.bmm(u, v), "c na nb -> na nb c")

    def use_planes(self, num_points: int) -> bool:
        """Whether ``strategy`` picks plane composition for a batch of ``num_points``."""
        if self.strategy != "auto":
            return self.strategy == "planes"
        n = self.grid_shape
        plane_elems = self.channels * (n[0] * n[1] + n[1] * n[2] + n[2] * n[0])
        return plane_elems < num_points * self.rank * self.channels

    def features_at(self, coords):
        if not self.use_planes(coords.shape[0]):
            return super().features_at(coords)
        return sum(interpolate(self.composed_plane(plane), coords[:, list(axes)]) for plane, axes in _PLANES.items())

    def spec(self):
        out = super().spec()
        if self.strategy != "auto":
            out["strategy"] = self.strategy
        return out
