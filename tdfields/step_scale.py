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

__all__ = ["step_scales", "scaled_param_groups"]


def _fields(module: nn.Module) -> list[tuple[str, Field]]:
    return [(name, m) for name, m in module.named_modules() if isinstance(m, Field)]


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
    for prefix, field in _fields(module):
        k = field.rank if field.has_rank else 1
        mean_sq = {}
        for fname, p in field.factors.items():
            v = float(p.detach().pow(2).mean())
            if not math.isfinite(v):
                raise ValueError(f"step_scales: factor {prefix + '.' if prefix else ''}factors.{fname} holds "
                                 "non-finite values")
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
                key = f"{prefix}.factors.{fname}" if prefix else f"factors.{fname}"
                out[key] = min(out.get(key, scale), scale)
    return out


#: ``scaled_param_groups`` modes: plain rates, the matched scale, or the matched scale where it is above 1 only
MODES = ("none", "matched", "lift")


def scaled_param_groups(module: nn.Module, lr: float, mode: str = "matched") -> list[dict]:
    """Optimizer parameter groups for ``module`` at base learning rate ``lr``: one group per distinct scale, in
    parameter order; parameters that are not field factors (decoders) keep ``lr``.

    ``mode``: ``"matched"``: ``lr * scale`` (:func:`step_scales`); ``"lift"``: ``lr * max(scale, 1)``, products
    slower than a plane are brought up to a plane's speed and faster ones keep ``lr`` (for rates tuned on planes);
    ``"none"``: one group at ``lr``.
    """
    if mode not in MODES:
        raise ValueError(f"scaled_param_groups: mode must be one of {MODES}, got {mode!r}")
    params = list(module.named_parameters())
    if mode == "none":
        return [{"params": [p for _, p in params], "lr": lr}] if params else []
    scales = step_scales(module)
    groups: dict[float, list[torch.Tensor]] = {}
    for name, p in params:
        s = scales.get(name, 1.0)
        groups.setdefault(max(s, 1.0) if mode == "lift" else s, []).append(p)
    return [{"params": ps, "lr": lr * s} for s, ps in groups.items()]
