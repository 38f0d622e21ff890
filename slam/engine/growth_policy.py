"""A map that grows: when a trusted frame's depth nears the scene box, the box grows on that side.

:meth:`SceneGrowth.decide` runs for every trusted frame with depth, where the loop submits its mapping call
(``SLAM._submit``), so both loop modes decide at the same frame. The frame's valid depth is back-projected with its
tracked pose (every ``s``-th pixel of every ``s``-th row, at most about 4k points: 1-2 ms on a CPU core) and
summarised per axis by its ``1 - q`` and ``q`` quantiles, ``q`` = ``scene.bound_auto_percentile`` / 100 (the share
of a frame's depth the automatic box counts, so a few stray far readings do not grow the box); with
``scene.grow_reach: box`` only the readings within the automatic box's starting half-size of the camera count (a
camera turning in place does not grow the box its first frames sized; one that moves does). A side whose quantile
comes within ``scene.grow_margin`` metres of the box (or passes it) grows by the whole coarse cells (the largest
``geometry.cell_sizes``) that put it ``grow_margin`` inside again. No axis grows past ``scene.grow_max_extent``
metres: a growth that would is cut to what fits, and an event says so (once per side).

:func:`grow_scene` applies a decision to a run. The growth itself is :meth:`slam.engine.map_worker.MapWorker.grow` (between mapping calls, every copy of the map
alike; :mod:`slam.model.box_resize` for the fields). Every growth is an event in ``metrics.json``: the sides and cells,
the new box, and the scene's parameters and field bytes after it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from slam.core.camera import backproject
from slam.core.pose import pose_to_matrix
from slam.model.scene import scene_size

#: the most points of a frame the decision looks at (a stride over rows and columns)
MAX_POINTS = 4096


@dataclass(frozen=True)
class GrowthStep:
    """One growth: metres added ``lower`` / ``upper`` per axis (whole coarse cells), and the cells per side
    (``{"x-": 2, "z+": 1}``)."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    cells: dict


def grow_box(box, step: GrowthStep) -> list[list[float]]:
    """A ``[3, 2]`` box in metres (the bound, the marching-cubes bound) grown as ``step`` grows the scene's."""
    return [[float(lo) - step.lower[a], float(hi) + step.upper[a]] for a, (lo, hi) in enumerate(box)]


def depth_reach(depth: torch.Tensor, pose: torch.Tensor, intr, q: float,
                radius: float | None = None) -> torch.Tensor | None:
    """``[2, 3]`` float64: the ``1 - q`` and ``q`` quantiles per axis of a frame's valid depth ``[H, W]`` (metres)
    back-projected with its camera-to-world ``pose`` ``[7]`` (world metres), counting only points within ``radius``
    metres of the camera when given; None without such depth."""
    h, w = depth.shape
    s = max(1, math.ceil(math.sqrt(h * w / MAX_POINTS)))
    z = depth[::s, ::s].float()
    v, u = torch.nonzero((z > 0) & torch.isfinite(z), as_tuple=True)
    if not len(v):
        return None
    pts = backproject((u * s).float(), (v * s).float(), z[v, u], intr.fx, intr.fy, intr.cx, intr.cy)
    if radius is not None:
        pts = pts[pts.norm(dim=1) <= radius]
        if not len(pts):
            return None
    T = pose_to_matrix(pose.detach().float().cpu()).to(pts.device)
    world = pts @ T[:3, :3].T + T[:3, 3]
    return torch.quantile(world, torch.tensor([1 - q, q], device=world.device), dim=0).double().cpu()


class SceneGrowth:
    """When and by how much the scene box grows (see the module docstring).

    Args:
        cfg: the run's config (``scene.grow*``, ``scene.bound``, ``scene.bound_auto_percentile``,
            ``geometry.cell_sizes``).
        event: ``event(k, what, **extra)``, the loop's event log.
        radius: metres, the automatic box's half-size at the start (None for a given box): with
            ``scene.grow_reach: box`` only depth within it of the camera counts.
    """

    def __init__(self, cfg, event, radius: float | None = None):
        sc = cfg.scene
        self.enabled = sc.grow is True or (sc.grow == "auto" and sc.bound == "auto")
        self.margin, self.max_extent = float(sc.grow_margin), float(sc.grow_max_extent)
        self.q = float(sc.bound_auto_percentile) / 100.0
        self.radius = radius if sc.grow_reach == "box" else None
        self.cell = float(max(cfg.geometry.cell_sizes))
        self.event = event
        self.capped: set[str] = set()  # sides whose growth the cap has cut (the event is logged once)

    def decide(self, k: int, depth: torch.Tensor, pose: torch.Tensor, intr, aabb: torch.Tensor) -> GrowthStep | None:
        """The growth frame ``k`` (depth ``[H, W]``, tracked pose ``[7]``) asks of the box ``aabb`` ``[3, 2]``, or
        None (growth off, or the depth is well inside)."""
        if not self.enabled:
            return None
        reach = depth_reach(depth, pose, intr, self.q, self.radius)
        if reach is None:
            return None
        box = aabb.detach().cpu().double()
        cells = {}
        for a in range(3):
            need = (float(box[a, 0] - reach[0, a]) + self.margin, float(reach[1, a] - box[a, 1]) + self.margin)
            want = [max(0, math.ceil(n / self.cell - 1e-9)) for n in need]
            room = max(0, math.floor((self.max_extent - float(box[a, 1] - box[a, 0])) / self.cell + 1e-9))
            got = [min(want[0], room)]
            got.append(min(want[1], room - got[0]))
            for side, n, asked in zip(("xyz"[a] + "-", "xyz"[a] + "+"), got, want):
                if n:
                    cells[side] = n
                if n < asked and side not in self.capped:
                    self.capped.add(side)
                    self.event(k, f"scene box not grown past scene.grow_max_extent = {self.max_extent} m on side "
                               f"{side} ({asked - n} coarse cell(s) short)", growth_capped=side)
        if not cells:
            return None
        lower = tuple(cells.get("xyz"[a] + "-", 0) * self.cell for a in range(3))
        upper = tuple(cells.get("xyz"[a] + "+", 0) * self.cell for a in range(3))
        return GrowthStep(lower, upper, cells)

    def grown(self, k: int, step: GrowthStep, aabb: torch.Tensor, size: tuple[int, int]) -> None:
        """Log the growth ``step`` made at frame ``k``: the new box ``aabb`` and the scene's ``(parameters,
        field_bytes)`` after it."""
        box = [[round(float(v), 4) for v in row] for row in aabb.tolist()]
        sides = ", ".join(f"{side} +{n}" for side, n in step.cells.items())
        self.event(k, f"scene box grown ({sides} cells of {self.cell} m): {box}, {size[0]:,} parameters",
                   growth={"sides": dict(step.cells), "cell_m": self.cell, "aabb": aabb.tolist(),
                           "parameters": int(size[0]), "field_bytes": int(size[1])})

    def state_dict(self) -> dict:
        """``{"capped"}``: the sides the cap has cut (plain data)."""
        return {"capped": sorted(self.capped)}

    def load_state_dict(self, state: dict) -> None:
        self.capped = set(state.get("capped", ()))


def grow_scene(system, k: int, depth: torch.Tensor) -> None:
    """Grow ``system``'s (a :class:`slam.engine.system.SLAM`) scene box where frame position ``k``'s depth
    ``[H, W]`` (metres) nears it, by its ``growth`` policy: every copy of the map, the bound and the marching-cubes
    bound alike, between mapping calls."""
    step = system.growth.decide(k, depth, system.state.est[-1], system.intr, system.aabb)
    if step is not None:
        system.mapper.grow(step.lower, step.upper)
        system.bound, system.mc_bound = grow_box(system.bound, step), grow_box(system.mc_bound, step)
        system.aabb, system.size = system.scene.aabb.detach().cpu().clone(), scene_size(system.scene)
        system.growth.grown(k, step, system.aabb, system.size)
