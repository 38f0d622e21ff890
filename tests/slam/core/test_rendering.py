import math

import torch

from slam.core.rendering import (camera_rays, composite_weights, pixel_directions, ray_box_exit, render_rays,
                            sample_depth_rays, sample_pdf, sample_pixels, sdf_to_alpha)


def test_pixel_directions_opencv():
    u = torch.tensor([10.0, 20.0])
    v = torch.tensor([5.0, 15.0])
    d = pixel_directions(u, v, fx=10.0, fy=20.0, cx=10.0, cy=5.0)
    assert torch.allclose(d, torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.5, 1.0]]))


def test_camera_rays_rotate_and_keep_depth_parameter():
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    c2w[:3, :3] = torch.tensor([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # camera z -> world x
    o, d = camera_rays(c2w, torch.tensor([[0.0, 0.0, 1.0]]))
    assert torch.allclose(o, torch.tensor([[1.0, 2, 3]]))
    assert torch.allclose(d, torch.tensor([[1.0, 0, 0]]))
    # batched poses
    o2, d2 = camera_rays(c2w[None].expand(1, 4, 4), torch.tensor([[0.0, 0.0, 1.0]]))
    assert torch.allclose(o2, o) and torch.allclose(d2, d)


def test_ray_box_exit():
    aabb = torch.tensor([[-1.0, 1.0], [-1.0, 1.0], [-1.0, 2.0]])
    o = torch.zeros(3, 3)
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.5, 1.0]])
    t = ray_box_exit(o, d, aabb)
    assert torch.allclose(t, torch.tensor([2.0, 1.0, 2.0]))


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


def test_composite_weights_hand_computed():
    alpha = torch.tensor([[0.5, 0.5, 1.0]])
    w = composite_weights(alpha)
    assert torch.allclose(w, torch.tensor([[0.5, 0.25, 0.25]]), atol=1e-6)
    # alpha from SDF without a delta term
    s = torch.tensor([0.0])
    a = sdf_to_alpha(s, 10.0)
    assert torch.allclose(a, torch.tensor([1 - math.exp(-5.0)]))


def test_sample_pdf_concentrates_on_heavy_bin():
    bins = torch.linspace(0, 1, 11).expand(4, 11)
    w = torch.zeros(4, 10)
    w[:, 6] = 1.0
    s = sample_pdf(bins, w, 50, generator=torch.Generator().manual_seed(0))
    # most samples inside the heavy bin [0.6, 0.7] (the unnormalised cdf may end beyond 1)
    inside = ((s >= 0.6 - 1e-6) & (s <= 0.7 + 1e-6)).float().mean()
    assert inside > 0.9


def test_render_rays_plane_depth():
    # a plane z = 2 in front of a camera at the origin: sdf = (2 - z) / T clipped
    T = 0.06

    def sdf(p):
        return torch.clamp((2.0 - p[:, 2]) / T, -1, 1)

    def rgb(p):
        return torch.full((p.shape[0], 3), 0.5)

    o = torch.zeros(16, 3)
    d = torch.cat((torch.zeros(16, 2), torch.ones(16, 1)), -1)
    D = torch.full((16,), 2.0)
    out = render_rays(o, d, D, sdf, rgb, 10.0, T, 32, 8, perturb=False)
    assert out.sdf.shape == (16, 40) and out.z.shape == (16, 40)
    assert torch.allclose(out.depth, D, atol=0.05)
    assert torch.allclose(out.color, torch.full((16, 3), 0.5), atol=0.02)


def test_render_rays_without_depth_uses_box():
    T = 0.06
    aabb = torch.tensor([[-1.0, 1.0], [-1.0, 1.0], [-1.0, 3.0]])

    def sdf(p):
        return torch.clamp((2.0 - p[:, 2]) / T, -1, 1)

    def rgb(p):
        return torch.full((p.shape[0], 3), 0.2)

    o = torch.zeros(4, 3)
    d = torch.cat((torch.zeros(4, 2), torch.ones(4, 1)), -1)
    D = torch.tensor([2.0, 0.0, 2.0, 0.0])
    out = render_rays(o, d, D, sdf, rgb, 10.0, T, 32, 8, aabb=aabb, perturb=True,
                      generator=torch.Generator().manual_seed(0))
    assert out.z[1].max() <= 3.01 + 1e-5
    assert torch.allclose(out.depth, torch.full((4,), 2.0), atol=0.1)


def test_sample_pixels_bounds_and_determinism():
    v, u = sample_pixels(100, 120, 1000, 10, 20, torch.Generator().manual_seed(1))
    assert v.min() >= 10 and v.max() < 90 and u.min() >= 20 and u.max() < 100
    v2, u2 = sample_pixels(100, 120, 1000, 10, 20, torch.Generator().manual_seed(1))
    assert torch.equal(v, v2) and torch.equal(u, u2)


def test_color_cutoff_queries_only_weighted_samples_and_bounds_the_change():
    T = 0.06
    queried = []

    def sdf(p):
        return torch.clamp((2.0 - p[:, 2]) / T, -1, 1)

    def rgb(p):
        queried.append(p.shape[0])
        return torch.stack((p[:, 2] / 4, torch.full_like(p[:, 0], 0.5), torch.full_like(p[:, 0], 0.25)), -1)

    o = torch.zeros(16, 3)
    d = torch.cat((torch.rand(16, 2) * 0.2, torch.ones(16, 1)), -1)
    D = torch.full((16,), 2.0)
    full = render_rays(o, d, D, sdf, rgb, 10.0, T, 32, 8, perturb=False)
    cut = render_rays(o, d, D, sdf, rgb, 10.0, T, 32, 8, perturb=False, color_cutoff=1e-3)
    assert queried[0] == 16 * 40 and queried[1] < 16 * 40 / 3  # most samples carry no weight
    skipped = (full.weights <= 1e-3).float() * full.weights
    assert (full.color - cut.color).abs().max() <= skipped.sum(-1).max() + 1e-6
    assert torch.equal(full.depth, cut.depth)
