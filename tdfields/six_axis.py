"""Six-axis (LRSLAM Eq. 3): each tri-plane plane replaced by its own rank-k CP factorisation. O(n)."""

from __future__ import annotations

from typing import ClassVar

import torch

from tdfields.field import FactorSpec, Field
from tdfields.ops import compose_plane
from tdfields.program import Plan, Program, single

# plane name -> (first axis, second axis); factor names are f"{plane}_{axis letter}"
_PLANES = {"xy": (0, 1), "yz": (1, 2), "zx": (2, 0)}
_AXIS = "xyz"
_PLANE_PROGRAM_TERMS = [(0,), (1,), (2,)]


class SixAxis(Field):
    """``f(p) = sum_i u_i(x) v_i(y) + sum_i p_i(y) q_i(z) + sum_i r_i(z) s_i(x)``, ``C``-vectors, rank ``k``.

    Parameters ``2 k C (n_x + n_y + n_z)``. Shapes: ``[..., 3]`` world metres -> ``[..., C]``.
    Factors ``xy_x [n_x, k*C]``, ``xy_y [n_y, k*C]``, ``yz_y``, ``yz_z``, ``zx_z``, ``zx_x`` (rank-major).

    Exact evaluation strategies, chosen per call by ``strategy``:

    * ``"factors"``: interpolate the six line factors at every point and multiply. Memory ``O(N k C)`` work
      per batch and ``O(n)`` in the grid: the strategy whose memory grows linearly with the scene.
    * ``"planes"``: first compose the three rank-k planes ``P_xy[x, y] = sum_i u_i[x] v_i[y]`` (a batched matmul,
      ``O(k C n^2)`` flops) and then interpolate them bilinearly. Bilinear interpolation of a separable product
      equals the product of the linear interpolations, so the result is the same up to float rounding, while the
      per-point work drops ``4k``-fold. The composed planes are temporaries of size
      ``C (n_x n_y + n_y n_z + n_z n_x)``.
    * ``"auto"`` (default): planes when composing them costs less than the per-point work of the factor path
      (large batches: mapping), and always inside :func:`tdfields.frozen` (tracking with a frozen map, meshing),
      where the composed planes are cached for the block.

    Sub-planes: outside a frozen block, only the region of each plane inside the points' bounding box (in grid
    cells) is composed, and the coordinates are shifted to it: the same values (each cell is composed
    independently), with composition work and plane gradients proportional to the region. On the TUM excerpt a
    mapping batch touches 32-52 % of each fine plane. Within the region the CPU kernel composes only the cells
    the points' interpolation reads (18-38 % of a fine sub-plane there; :func:`tdfields.ops.compose_plane`'s
    ``read_at``), the others 0: the same values at the points, bit for bit.

    Plane cache: only inside ``tdfields.frozen(field)`` (or a module holding it), dropped when the block is entered
    and left. Outside a block every query composes from the factors as they are, so no optimizer (fused Adam
    writes the factors without advancing their version counters), ``load_state_dict``, ``.data`` edit or resize
    can make a query read an old map. Inside a block, replaced tensors and version bumps still refresh it.
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
        self._plane_cache: tuple[list, list[torch.Tensor]] | None = None

    def factor_specs(self):
        w = self.rank * self.channels
        return {f"{plane}_{_AXIS[a]}": FactorSpec((a,), w) for plane, axes in _PLANES.items() for a in axes}

    def terms(self):
        return [(f"{plane}_{_AXIS[a]}", f"{plane}_{_AXIS[b]}") for plane, (a, b) in _PLANES.items()]

    def composed_plane(self, plane: str) -> torch.Tensor:
        """The rank-k plane ``P[a, b, c] = sum_i U[a, i, c] V[b, i, c]`` as ``[n_a, n_b, C]`` (differentiable)."""
        a, b = _PLANES[plane]
        return compose_plane(self.factors[f"{plane}_{_AXIS[a]}"], self.factors[f"{plane}_{_AXIS[b]}"], self.rank)

    def _needs_graph(self) -> bool:
        return torch.is_grad_enabled() and any(p.requires_grad for p in self.factors.values())

    def _caching(self) -> bool:
        return self.is_frozen and not self._needs_graph()

    def composed_planes(self) -> list[torch.Tensor]:
        """The three composed planes ``xy [n_x, n_y, C]``, ``yz [n_y, n_z, C]``, ``zx [n_z, n_x, C]``.

        Differentiable when a gradient to the factors is needed; cached inside :func:`tdfields.frozen`, composed
        afresh on every call otherwise.
        """
        if not self._caching():
            return [self.composed_plane(p) for p in _PLANES]
        factors = list(self.factors.values())
        key = [(p, p._version) for p in factors]
        cached = self._plane_cache
        if cached is None or len(cached[0]) != len(key) or any(
                a is not b or va != vb for (a, va), (b, vb) in zip(cached[0], key)):
            with torch.no_grad():
                planes = [self.composed_plane(p) for p in _PLANES]
            self._plane_cache = (key, planes)
        return self._plane_cache[1]

    def clear_cache(self) -> None:
        """Drop the cached composed planes (:func:`tdfields.frozen` does this on entry and exit)."""
        self._plane_cache = None

    def _apply(self, fn, *args, **kwargs):
        # .to() / .cuda() / .double() replace the factors; a cache from before would hold the old tensors alive
        self._plane_cache = None
        return super()._apply(fn, *args, **kwargs)

    def use_planes(self, num_points: int, extent: tuple[int, int, int] | None = None) -> bool:
        """Whether ``strategy`` picks plane composition for a batch of ``num_points`` whose bounding box spans
        ``extent`` samples per axis (default: the whole grid). Always inside a frozen block (cached planes)."""
        if self.strategy != "auto":
            return self.strategy == "planes"
        if self._caching():
            return True
        n = self.grid_shape if extent is None else extent
        plane_elems = self.channels * (n[0] * n[1] + n[1] * n[2] + n[2] * n[0])
        return plane_elems < num_points * self.rank * self.channels

    def _box(self, coords: torch.Tensor) -> tuple[list[int], list[int]]:
        """Lowest and highest sample index per axis that interpolation at ``coords [N, 3]`` reads."""
        if coords.shape[0] == 0:
            return [0, 0, 0], [1, 1, 1]
        c = coords.detach()
        lo = c.min(0).values.floor().tolist()
        hi = c.max(0).values.ceil().tolist()
        lows, highs = [], []
        for a, n in enumerate(self.grid_shape):
            if not (lo[a] == lo[a] and hi[a] == hi[a]):  # NaN coordinates: keep the whole axis
                lo[a], hi[a] = 0, n - 1
            first = min(max(int(lo[a]), 0), n - 2)
            lows.append(first)
            highs.append(max(min(int(hi[a]), n - 1), first + 1))
        return lows, highs

    def plan_at(self, coords: torch.Tensor) -> Plan:
        """The plan at ``coords [1, N, 3]``: inside a frozen block or with ``strategy="factors"`` the whole-grid
        program; else, where composing planes pays (:meth:`use_planes`), the planes over the points' bounding box
        (sub-planes) and the coordinates shifted to them, or the factors."""
        if self._caching() or self.strategy == "factors":
            return super().plan_at(coords)
        points = coords[0]
        lo, hi = self._box(points)
        extent = tuple(h - l_ + 1 for l_, h in zip(lo, hi))
        if not self.use_planes(points.shape[0], extent):
            program, tensors = super().whole_grid_program(points.shape[0])
            return Plan(program, tuple(tensors), coords)
        shift = torch.tensor(lo, dtype=coords.dtype, device=coords.device)
        shifted = coords - shift
        read = shifted.detach()[0]
        planes = []
        for plane, (a, b) in _PLANES.items():
            u, v = self.factors[f"{plane}_{_AXIS[a]}"], self.factors[f"{plane}_{_AXIS[b]}"]
            # only the cells this plan's points read are composed (where the kernel does): a fifth to a third
            planes.append(compose_plane(u, v, self.rank, read_at=read[:, [a, b]],
                                        rows=((lo[a], hi[a] + 1), (lo[b], hi[b] + 1))))
        program = single(list(_PLANES.values()), _PLANE_PROGRAM_TERMS, [1, 1, 1], self.channels)
        return Plan(program, tuple(planes), shifted)

    def whole_grid_program(self, num_points: int) -> tuple[Program, list[torch.Tensor]]:
        if not self.use_planes(num_points):
            return super().whole_grid_program(num_points)
        program = single(list(_PLANES.values()), _PLANE_PROGRAM_TERMS, [1, 1, 1], self.channels)
        return program, self.composed_planes()

    def spec(self):
        out = super().spec()
        if self.strategy != "auto":
            out["strategy"] = self.strategy
        return out
