"""Sample depths along rays, ESLAM's way: stratified over the measured depth's range plus evenly spaced samples
around it, NeRF's jitter within midpoint intervals, and inverse-CDF (importance) sampling of weights. Depths are
along the camera axis in metres (docs/data.md); nothing here carries a gradient.
"""

from __future__ import annotations

import torch


def perturb_depths(z: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """NeRF stratified jitter: each sample uniform within its midpoint interval (``z`` sorted ``[R, N]``)."""
    mids = 0.5 * (z[..., 1:] + z[..., :-1])
    upper = torch.cat((mids, z[..., -1:]), -1)
    lower = torch.cat((z[..., :1], mids), -1)
    t = torch.rand(z.shape, generator=generator, dtype=z.dtype, device="cpu").to(z.device)
    return lower + (upper - lower) * t


def sample_depth_rays(
    depth: torch.Tensor,
    n_stratified: int,
    n_importance: int,
    truncation: float,
    perturb: bool = True,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Sample depths for rays with a valid measurement ``D > 0`` (ESLAM).

    ``n_stratified`` evenly spaced values on ``[0, 1.2 D]`` plus ``n_importance`` evenly spaced values on
    ``[D - 1.5 T, D + 1.5 T]``, sorted, then jittered within midpoint intervals.

    Args:
        depth: ``[R]`` measured depth, metres (> 0).

    Returns:
        ``[R, n_stratified + n_importance]`` sorted sample depths (no gradient).
    """
    d = depth.detach()[:, None]
    lin_s = torch.linspace(0.0, 1.0, n_stratified, dtype=d.dtype, device=d.device)
    z = [1.2 * d * lin_s]
    if n_importance > 0:
        lin_i = torch.linspace(-1.5 * truncation, 1.5 * truncation, n_importance, dtype=d.dtype, device=d.device)
        z.append(d + lin_i)
    z = torch.sort(torch.cat(z, -1), -1).values
    return perturb_depths(z, generator) if perturb else z


def sample_pdf(bins: torch.Tensor, weights: torch.Tensor, n: int, generator: torch.Generator | None = None,
               deterministic: bool = False) -> torch.Tensor:
    """Inverse-CDF sampling (NeRF ``sample_pdf``) with ESLAM's quirk: the pdf is the raw weights, unnormalised.

    Args:
        bins: ``[R, M + 1]`` bin edges.
        weights: ``[R, M]`` non-negative weights.
        n: samples per ray.

    Returns:
        ``[R, n]`` samples (no gradient).
    """
    weights = weights.detach() + 1e-5
    pdf = weights  # ESLAM: pdf overwritten by the raw weights (not divided by the sum)
    cdf = torch.cumsum(pdf, -1)
    cdf = torch.cat((torch.zeros_like(cdf[..., :1]), cdf), -1)
    if deterministic:
        u = torch.linspace(0.0, 1.0, n, dtype=bins.dtype, device=bins.device).expand(cdf.shape[0], n)
    else:
        u = torch.rand((cdf.shape[0], n), generator=generator, dtype=bins.dtype, device="cpu").to(bins.device)
    u = u.contiguous()
    inds = torch.searchsorted(cdf.contiguous(), u, right=True)
    below = (inds - 1).clamp(min=0)
    above = inds.clamp(max=cdf.shape[-1] - 1)
    cdf_b = torch.gather(cdf, -1, below)
    cdf_a = torch.gather(cdf, -1, above)
    bins_b = torch.gather(bins, -1, below)
    bins_a = torch.gather(bins, -1, above)
    denom = cdf_a - cdf_b
    denom = torch.where(denom < 1e-5, torch.ones_like(denom), denom)
    t = (u - cdf_b) / denom
    return bins_b + t * (bins_a - bins_b)
