"""ESLAM's sample depths: evenly spaced around the measurement, jittered within their intervals, and inverse-CDF
samples that follow the weights."""

import torch

from slam.core.sampling import sample_depth_rays, sample_pdf


def test_sample_depth_rays_unperturbed():
    D = torch.tensor([1.0, 2.0])
    z = sample_depth_rays(D, n_stratified=5, n_importance=3, truncation=0.1, perturb=False)
    assert z.shape == (2, 8)
    assert torch.all(z[:, 1:] >= z[:, :-1])
    expect0 = sorted([0.0, 0.3, 0.6, 0.9, 1.2, 0.85, 1.0, 1.15])
    assert torch.allclose(z[0], torch.tensor(expect0), atol=1e-6)


def test_sample_depth_rays_perturbed_within_intervals():
    g = torch.Generator().manual_seed(0)
    D = torch.full((100,), 2.0)
    z0 = sample_depth_rays(D, 8, 4, 0.06, perturb=False)
    z = sample_depth_rays(D, 8, 4, 0.06, perturb=True, generator=g)
    mids = 0.5 * (z0[:, 1:] + z0[:, :-1])
    lo = torch.cat((z0[:, :1], mids), -1)
    hi = torch.cat((mids, z0[:, -1:]), -1)
    assert torch.all(z >= lo - 1e-6) and torch.all(z <= hi + 1e-6)


def test_sample_pdf_concentrates_on_heavy_bin():
    bins = torch.linspace(0, 1, 11).expand(4, 11)
    w = torch.zeros(4, 10)
    w[:, 6] = 1.0
    s = sample_pdf(bins, w, 50, generator=torch.Generator().manual_seed(0))
    # most samples inside the heavy bin [0.6, 0.7] (the unnormalised cdf may end beyond 1)
    inside = ((s >= 0.6 - 1e-6) & (s <= 0.7 + 1e-6)).float().mean()
    assert inside > 0.9
