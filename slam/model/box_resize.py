"""Growing the scene's box: every field level grows by whole samples of its own grid, so nothing is resampled.

A level's samples lie ``extent / (n - 1)`` apart (sample 0 on the box's lower face, ``n - 1`` on the upper one, ``n =
floor(extent / cell)``), which is not its cell size and differs between levels (0.24 m cells over 4.32 m: 18
samples 0.254 m apart; 0.06 m cells: 72 samples 0.0608 m apart), so no one distance is a whole number of samples of
every level. The scene's box (``SceneModel.aabb``, what rendering clips rays to) grows by the metres asked, and each
level by the fewest whole samples of its own spacing that cover it (:func:`tdfields.grow`): the old samples are
copied bit for bit, the new ones copy the border, so the map answers as before wherever it was queried, up to the
float32 rounding of the grown boxes. :class:`ScenePads` records what each level got, so the same growth applies to
another copy of the map (the tracker's) and to a saved ``state_dict`` of the old size (:func:`pad_state`: the maps
pending mapping calls left); :func:`fit_to_state` shapes a freshly built scene like a saved, grown one before
``load_state_dict``, and :func:`load_scene_state` does both (a resumed run, the mapping process's replica,
``lrslam mesh``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import nn

import tdfields
from tdfields.resize import grown_aabb, pad_factor


@dataclass(frozen=True)
class LevelPad:
    """One field level's growth: samples added ``lower`` / ``upper`` per axis, its new ``(3, 2)`` box, and the axes
    each of its factors spans (factor name -> axes)."""

    lower: tuple[int, int, int]
    upper: tuple[int, int, int]
    aabb: torch.Tensor
    axes: dict


@dataclass(frozen=True)
class ScenePads:
    """A scene's growth: its new ``(3, 2)`` box (float32, metres) and each level's :class:`LevelPad` by module
    name (``fields.geometry.levels.0``...)."""

    aabb: torch.Tensor
    levels: dict


def _levels(scene: nn.Module) -> list[tuple[str, tdfields.Field]]:
    return [(name, m) for name, m in scene.named_modules() if isinstance(m, tdfields.Field)]


def plan_growth(scene: nn.Module, lower: Sequence[float], upper: Sequence[float]) -> ScenePads:
    """The growth of ``scene`` (anything with an ``aabb`` buffer holding tdfields fields) by ``lower`` / ``upper``
    metres per axis (each >= 0): the scene's new box and, per level, the fewest whole samples covering it."""
    box = scene.aabb.detach().cpu().double()
    new = torch.stack([box[:, 0] - torch.as_tensor(lower, dtype=torch.float64),
                       box[:, 1] + torch.as_tensor(upper, dtype=torch.float64)], dim=-1).float()
    levels = {}
    for name, field in _levels(scene):
        fbox = field.aabb.detach().cpu().double()
        step = (fbox[:, 1] - fbox[:, 0]) / (torch.as_tensor(field.grid_shape, dtype=torch.float64) - 1)
        # 1e-6 samples of slack: a distance that is a whole number of samples up to rounding takes that number
        lo = tuple(max(0, math.ceil(float((fbox[a, 0] - new[a, 0]) / step[a]) - 1e-6)) for a in range(3))
        hi = tuple(max(0, math.ceil(float((new[a, 1] - fbox[a, 1]) / step[a]) - 1e-6)) for a in range(3))
        levels[name] = LevelPad(lo, hi, grown_aabb(field.aabb.detach().cpu(), field.grid_shape, lo, hi),
                                {f: spec.axes for f, spec in field.factor_specs().items()})
    return ScenePads(new, levels)


@torch.no_grad()
def apply_growth(scene: nn.Module, pads: ScenePads) -> None:
    """Grow ``scene`` in place as ``pads`` says (new parameters for every factor: rebuild optimizers after)."""
    for name, field in _levels(scene):
        pad = pads.levels[name]
        tdfields.grow(field, pad.lower, pad.upper)
    scene.aabb.copy_(pads.aabb.to(scene.aabb))


def pad_state(state: dict, pads: ScenePads) -> dict:
    """A scene ``state_dict`` of the size before ``pads`` -> the ``state_dict`` of that scene grown by ``pads``
    (what :func:`apply_growth` then ``state_dict()`` gives; other entries are kept as they are)."""
    out = dict(state)
    for name, pad in pads.levels.items():
        for factor, axes in pad.axes.items():
            key = f"{name}.factors.{factor}"
            out[key] = pad_factor(state[key], axes, pad.lower, pad.upper)
        out[f"{name}.aabb"] = pad.aabb.to(state[f"{name}.aabb"])
    out["aabb"] = pads.aabb.to(state["aabb"])
    return out


def fit_to_state(scene: nn.Module, state: dict) -> None:
    """Shape every field level of ``scene`` like the levels saved in ``state`` (a scene ``state_dict``, grown or
    not): grid and box, so that ``load_state_dict(state)`` fits. The values are then ``load_state_dict``'s to set;
    levels ``state`` lacks are left as they are (``load_state_dict`` names them)."""
    for name, field in _levels(scene):
        shape = list(field.grid_shape)
        try:
            for factor, spec in field.factor_specs().items():
                saved = state[f"{name}.factors.{factor}"]
                for dim, a in enumerate(spec.axes):
                    shape[a] = int(saved.shape[dim])
            box = state[f"{name}.aabb"]
        except KeyError:
            continue
        if tuple(shape) != tuple(field.grid_shape):
            tdfields.resize(field, grid_shape=shape, aabb=box.cpu())


def load_scene_state(scene: nn.Module, state: dict) -> None:
    """``scene.load_state_dict(state)`` for a saved scene ``state_dict`` whose box may have grown: every level is
    first shaped like the saved one (:func:`fit_to_state`), then takes its values.

    Raises:
        RuntimeError: ``state`` is not this scene's (``load_state_dict``'s: missing keys or other shapes)."""
    with torch.no_grad():
        fit_to_state(scene, state)
        scene.load_state_dict(state)
