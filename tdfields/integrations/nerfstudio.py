"""Any tdfields field spec as a nerfstudio ``Encoding`` (docs/nerf.md, "nerfstudio plugin").

nerfstudio's fields hand their encodings positions already normalised to the scene box: TensoRF's field passes
``2 * SceneBox.get_normalized_positions(x) - 1``, in ``[-1, 1]`` (the ``grid_sample`` convention of its own
TensoRF encodings), nerfacto's hash grid ``[0, 1]``. :class:`TDFieldsEncoding` maps that range (``input_range``)
linearly onto the field's box, so the field is queried at the same place whatever the box's units::

    from tdfields.integrations.nerfstudio import TDFieldsEncoding
    enc = TDFieldsEncoding({"kind": "cp", "aabb": [[-1, 1]] * 3, "grid_shape": [64] * 3, "channels": 16, "rank": 8})
    feats = enc(positions)                 # [..., 3] in [-1, 1] -> [..., 16]

This module imports nerfstudio; ``import tdfields`` never imports it.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import torch
from torch import nn

import tdfields

try:
    from nerfstudio.field_components.encodings import Encoding
except ImportError as exc:  # nerfstudio, or one of the packages its encodings import, is missing
    raise ImportError(
        "tdfields.integrations.nerfstudio needs nerfstudio: pip install 'tdfields[nerfstudio]' "
        '(the offline recipe beside a CPU-only torch: docs/nerf.md, "nerfstudio plugin"). '
        f"The import failed with: {exc}") from exc

__all__ = ["TDFieldsEncoding", "field_box", "fields_in", "rescale_moments", "scaled_shape"]


def fields_in(module: nn.Module) -> list[tdfields.Field]:
    """Every :class:`tdfields.Field` inside ``module`` (itself, a MultiResolution's levels, a Hybrid's fields)."""
    return [m for m in module.modules() if isinstance(m, tdfields.Field)]


def field_box(module: nn.Module) -> torch.Tensor:
    """``(3, 2)`` box in the field's units (metres for tdfields' own fields): the union of every field's box."""
    boxes = torch.stack([f.aabb for f in fields_in(module)])
    return torch.stack([boxes[:, :, 0].min(0).values, boxes[:, :, 1].max(0).values], dim=-1)


def scaled_shape(shape: Sequence[int], factor: float) -> tuple[int, int, int]:
    """A grid shape with every axis scaled by ``factor`` (at least 2 samples per axis)."""
    return tuple(max(2, round(n * factor)) for n in shape)  # type: ignore[return-value]


class TDFieldsEncoding(Encoding):
    """A tdfields field (or MultiResolution, or Hybrid) as a nerfstudio encoding.

    Args:
        spec: a tdfields spec (dict, YAML path, config) or an already built field module.
        input_range: ``(a, b)``: the normalised coordinate range the calling nerfstudio field passes, mapped onto
            the field's box (``a`` on its lower faces, ``b`` on its upper faces). ``(-1, 1)`` for TensoRF's field,
            ``(0, 1)`` for fields that pass ``SceneBox.get_normalized_positions`` unchanged (nerfacto's).

    ``forward``: ``[..., 3]`` normalised coordinates -> ``[..., get_out_dim()]`` features, the leading dims kept;
    a Hybrid's fields are concatenated in name order. Points outside the range read the box's border (tdfields
    clamps). Gradients reach the factors and the coordinates.
    """

    def __init__(self, spec, input_range: tuple[float, float] = (-1.0, 1.0)) -> None:
        super().__init__(in_dim=3)
        self.field = spec if isinstance(spec, nn.Module) else tdfields.build(spec)
        if not fields_in(self.field):
            raise TypeError(f"TDFieldsEncoding: {type(self.field).__name__} holds no tdfields.Field")
        a, b = (float(v) for v in input_range)
        if not b > a:
            raise ValueError(f"TDFieldsEncoding: input_range must be (a, b) with b > a, got {input_range}")
        self.input_range = (a, b)

    def get_out_dim(self) -> int:
        """Feature width: the field's ``out_dim`` (a Hybrid's widths summed)."""
        if isinstance(self.field, tdfields.Hybrid):
            return sum(f.out_dim for f in self.field.values())
        return self.field.out_dim

    def to_field(self, coords: torch.Tensor) -> torch.Tensor:
        """``[..., 3]`` normalised coordinates -> ``[..., 3]`` points in the field's box (its units)."""
        box = field_box(self.field).to(coords)
        a, b = self.input_range
        return box[:, 0] + (coords - a) * ((box[:, 1] - box[:, 0]) / (b - a))

    def forward(self, in_tensor: torch.Tensor) -> torch.Tensor:
        """``[..., 3]`` normalised coordinates -> ``[..., C]`` features."""
        out = self.field(self.to_field(in_tensor))
        if isinstance(out, Mapping):  # a Hybrid: one feature block per named field
            return torch.cat([out[name] for name in self.field.names()], dim=-1)
        return out

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """The finest field's samples per axis."""
        return max((f.grid_shape for f in fields_in(self.field)), key=lambda s: s[0] * s[1] * s[2])

    def upsample_grid(self, resolution: int, optimizer: torch.optim.Optimizer | None = None,
                      adam_state: str = "keep") -> None:
        """Resample every field so the finest one has ``resolution`` samples along its longest axis (the others
        scaled alike), with :func:`tdfields.resize`.

        With ``optimizer`` (one holding the factors, e.g. nerfstudio's ``encodings`` Adam) the new factors take the
        old ones' places in its param groups, so training goes on in the same optimizer (nerfstudio's own encodings
        take ``resolution`` alone and need a new one). ``adam_state`` says what becomes of the factors' state:

        * ``"keep"``: resampled with the factors (Adam's step count kept) and rescaled to the finer grid's
          gradients (:func:`rescale_moments`);
        * ``"reset"``: dropped, so Adam starts the factors afresh (full-size first steps), as a new optimizer
          would, while the other parameters' state, the optimizer and its learning-rate schedule stay.
        """
        if adam_state not in ("keep", "reset"):
            raise ValueError(f"adam_state must be keep or reset, got {adam_state!r}")
        factor = int(resolution) / max(self.grid_shape)
        for f in fields_in(self.field):
            old_shape = f.grid_shape
            tdfields.resize(f, grid_shape=scaled_shape(old_shape, factor), optimizer=optimizer)
            if optimizer is None:
                continue
            if adam_state == "keep":
                rescale_moments(f, old_shape, optimizer)
            else:
                for p in f.factors.values():
                    optimizer.state.pop(p, None)


def rescale_moments(field: tdfields.Field, old_shape: Sequence[int], optimizer: torch.optim.Optimizer) -> None:
    """Scale Adam's moments of ``field``'s factors, just resampled from ``old_shape``, to the gradients they will
    now get: a factor sample collects the gradient of the points in its cells, so on a grid ``r`` times finer along
    each axis it spans it gets about ``1 / r`` per axis. ``exp_avg`` is multiplied by that ratio and ``exp_avg_sq``
    (and ``max_exp_avg_sq``) by its square. Resampled alone, the second moments would be ``r^2`` too large and
    shrink every step ``r``-fold until they decay (beta2 = 0.999: about a thousand steps)."""
    for name, spec in field.factor_specs().items():
        state = optimizer.state.get(field.factors[name], {})
        ratio = 1.0
        for a in spec.axes:
            ratio *= old_shape[a] / field.grid_shape[a]
        for key, power in (("exp_avg", 1), ("exp_avg_sq", 2), ("max_exp_avg_sq", 2)):
            if torch.is_tensor(state.get(key)):
                state[key].mul_(ratio ** power)
