"""The SLAM scene model: geometry + appearance feature fields (built by :func:`tdfields.build` from the config),
the SDF and RGB decoders and the sharpness ``beta``. No factorisation maths lives here.

Parameter names (used by :func:`tdfields.report` prefixes): ``fields.geometry.*``, ``fields.appearance.*``
(e.g. ``fields.geometry.levels.1.factors.x``), ``sdf_decoder.*``, ``rgb_decoder.*``, ``beta``. Checkpoints written
with the earlier ``fields.fields.*`` names still load (:class:`tdfields.Hybrid` maps them).
"""

from __future__ import annotations

import torch
from torch import nn

import tdfields
from tdfields.step_scale import scaled_param_groups
from slam.config import Config, FieldSpec


def field_spec(spec: FieldSpec, aabb: torch.Tensor) -> dict:
    """tdfields multi-resolution spec for one quantity (one level per cell size, same kind/rank/channels)."""
    levels = []
    for cell in spec.cell_sizes:
        level = {"kind": spec.kind, "aabb": aabb.tolist(), "cell_size": float(cell), "channels": int(spec.channels)}
        if tdfields.KINDS[spec.kind].has_rank:
            level["rank"] = int(spec.rank)
        if spec.init_std is not None:
            level["init_std"] = float(spec.init_std)
        levels.append(level)
    return {"kind": "multires", "levels": levels}


class SceneModel(nn.Module):
    """Geometry/appearance fields + decoders.

    Args:
        cfg: resolved config (``geometry``, ``appearance``, ``scene``).
        aabb: ``(3, 2)`` enlarged scene box in metres (see :func:`tdfields.enlarge_bounds`).

    :meth:`sdf` and :meth:`rgb` are the two callables :func:`slam.core.rendering.render_rays` takes.
    """

    def __init__(self, cfg: Config, aabb: torch.Tensor):
        super().__init__()
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).clone())
        self.fields = tdfields.Hybrid(
            {
                "geometry": tdfields.build(field_spec(cfg.geometry, self.aabb)),
                "appearance": tdfields.build(field_spec(cfg.appearance, self.aabb)),
            }
        )
        hidden = cfg.scene.decoder_hidden
        self.sdf_decoder = tdfields.MLPDecoder(self.fields["geometry"].out_dim, 1, hidden=hidden,
                                               output_activation="tanh")
        self.rgb_decoder = tdfields.MLPDecoder(self.fields["appearance"].out_dim, 3, hidden=hidden,
                                               output_activation="sigmoid")
        beta = torch.tensor(float(cfg.scene.beta_init))
        if cfg.scene.learnable_beta:
            self.beta = nn.Parameter(beta)
        else:
            self.register_buffer("beta", beta)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """``[P, 3]`` world metres -> ``[P]`` normalised SDF in (-1, 1) (tanh; times the truncation: metres)."""
        return self.sdf_decoder(self.fields["geometry"](points))[..., 0]

    def rgb(self, points: torch.Tensor) -> torch.Tensor:
        """``[P, 3]`` world metres -> ``[P, 3]`` RGB in (0, 1)."""
        return self.rgb_decoder(self.fields["appearance"](points))

    def param_groups(self, cfg: Config, factor: float = 1.0, scaling: str = "none") -> list[dict]:
        """Adam groups with the mapping learning rates (decoders incl. beta, geometry, appearance).

        ``scaling`` (``none`` / ``matched`` / ``lift``): the field factors' rates times their step scales as the
        factors are now (:func:`tdfields.scaled_param_groups`; tri-planes and grids keep exactly their rate)."""
        m = cfg.mapping
        dec = list(self.sdf_decoder.parameters()) + list(self.rgb_decoder.parameters())
        if isinstance(self.beta, nn.Parameter):
            dec.append(self.beta)
        return [{"params": dec, "lr": m.lr_decoders * factor},
                *scaled_param_groups(self.fields["geometry"], m.lr_geometry * factor, scaling),
                *scaled_param_groups(self.fields["appearance"], m.lr_appearance * factor, scaling)]


def parameter_counts(model: SceneModel) -> dict[str, int]:
    """``{"geometry", "appearance", "decoders", "total"}`` from :func:`tdfields.report` (never hand-written)."""
    rep = tdfields.report(model)
    geo = rep.parameters_under("fields.geometry")
    app = rep.parameters_under("fields.appearance")
    total = rep.total_parameters
    return {"geometry": geo, "appearance": app, "decoders": total - geo - app, "total": total}


def scene_size(model: SceneModel) -> tuple[int, int]:
    """``(parameters, field_bytes)``: every trainable scalar of the scene, and the bytes its fields' factors hold
    (from :func:`tdfields.report`; Adam keeps about three times the field bytes again while mapping)."""
    rep = tdfields.report(model)
    return rep.total_parameters, sum(row.bytes for row in rep.rows)


def scene_aabb(bound, dividable: float) -> torch.Tensor:
    """ESLAM's enlarged bound (float32)."""
    return tdfields.enlarge_bounds(bound, multiple=dividable)
