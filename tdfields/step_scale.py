"""Learning-rate scales that give a product of factors the step size of a plane under Adam.

Adam (and every sign-like optimizer) moves each parameter by about ``lr`` per step, whatever its gradient's size.
For a tri-plane or a dense grid that is a feature step of ``lr``: the feature *is* the parameter. A product term
``sum_{r<k} f_1 * ... * f_d`` (CP: three lines, Six-axis: two, VM: a plane and a line) moves, to first order, by
``sum_r sum_i step(f_i) * prod_{j != i} f_j``. A line factor's entry is shared by every point of its slice, so the
sign of its step is set by gradients summed over many points and is, at any one point, about as likely to help as
to hurt: the ``k * d`` contributions add up like a random walk, to a root-mean-square feature step of

    lr * sqrt(k * sum_i prod_{j != i} E[f_j^2])

(``k``: rank, 1 for kinds without one). The scale is the inverse of that root, so one step of every kind moves
each term's features by about ``lr``. Measured on LRSLAM's factors after mapping 125 TUM frames at plain rates:
about 2.1 for rank-2 CP geometry (factors around 0.4: its products move at half a plane's speed) and about 0.6 for
rank-16 Six-axis appearance (1.7x a plane's speed). At high rank some of the contributions stay coherent, so the
estimate is approximate there (tests/tdfields/test_step_scale.py: within 0.9-1.25x of a plane at rank 2).
Single-factor terms (tri-plane, dense grid) get exactly ``1.0``: their learning rates are unchanged.

The scale depends on the factors' current size, so recompute it when they have changed (``slam`` does, once per
mapping call). Near a small random initialisation it is large (CP at ``init_std`` 0.1: about 40x), which is why
LRSLAM's mapper applies it only after the first frame's warm-up.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from tdfields.field import Field

__all__ = ["MODES", "step_scales", "rate_scales", "scaled_param_groups"]


@torch.no_grad()
def step_scales(module: nn.Module) -> dict[str, float]:
    """Parameter name (as in ``module.named_parameters()``) -> learning-rate scale, for every factor of every
    :class:`tdfields.Field` inside ``module`` (the module itself, a :class:`tdfields.MultiResolution`, a
    :class:`tdfields.Hybrid`, or any module holding fields). Parameters that are not field factors (decoders)
    are not listed. A factor in several terms takes the smallest of their scales (the most cautious step).

    Raises:
        ValueError: a factor holds a non-finite value, or a term's factors are all zero (no finite scale).
    """
    out: dict[str, float] = {}
    for prefix, field in module.named_modules():
        if not isinstance(field, Field):
            continue
        k = field.rank if field.has_rank else 1
        keys = {fname: f"{prefix}.factors.{fname}" if prefix else f"factors.{fname}" for fname in field.factors}
        mean_sq = {}
        for fname, p in field.factors.items():
            v = float(p.detach().pow(2).mean())
            if not math.isfinite(v):
                raise ValueError(f"step_scales: factor {keys[fname]} holds non-finite values")
            mean_sq[fname] = v
        for term in field.terms():
            if len(term) == 1:
                scale = 1.0
            else:
                m = [mean_sq[f] for f in term]
                s = math.sqrt(k * sum(math.prod(m[:i] + m[i + 1:]) for i in range(len(m))))
                if not s > 0:
                    raise ValueError(f"step_scales: the factors {term} of {prefix or type(field).__name__} are "
                                     "all zero; a product of zero factors has no gradient to scale")
                scale = 1.0 / s
            for fname in term:
                out[keys[fname]] = min(out.get(keys[fname], scale), scale)
    return out


#: modes: plain rates, the matched scale, or the matched scale where it is above 1 only
MODES = ("none", "matched", "lift")


def rate_scales(module: nn.Module, mode: str = "matched") -> dict[str, float]:
    """Parameter name -> learning-rate multiplier for every parameter of ``module`` under ``mode``.

    ``"matched"``: the :func:`step_scales` scale; ``"lift"``: ``max(scale, 1)``, products slower than a plane are
    brought up to a plane's speed and faster ones keep their rate (for rates tuned on planes); ``"none"``: 1.0.
    Parameters that are not field factors (decoders) get 1.0.
    """
    if mode not in MODES:
        raise ValueError(f"step_scale: mode must be one of {MODES}, got {mode!r}")
    scales = step_scales(module) if mode != "none" else {}
    out = {}
    for name, _ in module.named_parameters():
        s = scales.get(name, 1.0)
        out[name] = max(s, 1.0) if mode == "lift" else s
    return out


def scaled_param_groups(module: nn.Module, lr: float, mode: str = "matched") -> list[dict]:
    """Optimizer parameter groups for ``module`` at base learning rate ``lr``: ``lr`` times each parameter's
    :func:`rate_scales` multiplier, one group per distinct multiplier, in parameter order (``"none"``: one group
    at ``lr``)."""
    scales = rate_scales(module, mode)
    groups: dict[float, list[torch.Tensor]] = {}
    for name, p in module.named_parameters():
        groups.setdefault(scales[name], []).append(p)
    return [{"params": ps, "lr": lr * s} for s, ps in groups.items()]
