import math

import torch

from slam.core.rendering import camera_rays, composite_weights, ray_box_exit, render_pixels, render_rays, sdf_to_alpha


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


def test_composite_weights_hand_computed():
    alpha = torch.tensor([[0.5, 0.5, 1.0]])
    w = composite_weights(alpha)
    assert torch.allclose(w, torch.tensor([[0.5, 0.25, 0.25]]), atol=1e-6)
    # alpha from SDF without a delta term
    s = torch.tensor([0.0])
    a = sdf_to_alpha(s, 10.0)
    assert torch.allclose(a, torch.tensor([1 - math.exp(-5.0)]))


def _plane(T: float, grey: float):
    """A plane z = 2 in front of a camera at the origin (sdf = (2 - z) / T, clipped) of one grey."""
    return (lambda p: torch.clamp((2.0 - p[:, 2]) / T, -1, 1)), (lambda p: torch.full((p.shape[0], 3), grey))


def test_render_rays_plane_depth():
    T = 0.06
    sdf, rgb = _plane(T, 0.5)
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
    sdf, rgb = _plane(T, 0.2)
    o = torch.zeros(4, 3)
    d = torch.cat((torch.zeros(4, 2), torch.ones(4, 1)), -1)
    D = torch.tensor([2.0, 0.0, 2.0, 0.0])
    out = render_rays(o, d, D, sdf, rgb, 10.0, T, 32, 8, aabb=aabb, perturb=True,
                      generator=torch.Generator().manual_seed(0))
    assert out.z[1].max() <= 3.01 + 1e-5
    assert torch.allclose(out.depth, torch.full((4,), 2.0), atol=0.1)


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


def test_render_pixels_keeps_rays_inside_the_box_and_with_depth_when_asked():
    """The one path from pixels to a render: a plane at z = 2 seen from the origin; pixels whose reading lies
    beyond the box, or have none, are dropped exactly as asked, and the rest render the plane's depth."""
    from types import SimpleNamespace

    T = 0.1
    scene = SimpleNamespace(sdf=lambda p: torch.clamp((2.0 - p[:, 2]) / T, -1, 1),
                            rgb=lambda p: torch.full((p.shape[0], 3), 0.5), beta=torch.tensor(10.0),
                            aabb=torch.tensor([[-5.0, 5.0], [-5.0, 5.0], [0.0, 2.5]]))
    intr = SimpleNamespace(fx=10.0, fy=10.0, cx=5.0, cy=5.0)
    rendering = SimpleNamespace(n_stratified=32, n_importance=8, color_cutoff=0.0, fused=False)
    u, v = torch.tensor([5, 5, 6, 4]), torch.tensor([5, 4, 5, 6])
    depth = torch.tensor([2.0, 0.0, 3.0, 2.0])  # the third reading is beyond the box (z <= 2.5)
    color = torch.rand(4, 3)
    args = dict(u=u, v=v, depth=depth, color=color, c2w=torch.eye(4), intrinsics=intr, rendering=rendering,
                truncation=T, perturb=False, generator=None)
    out, D, C = render_pixels(scene, depth_required=True, **args)
    assert torch.equal(D, depth[[0, 3]]) and torch.equal(C, color[[0, 3]])
    assert torch.allclose(out.depth, torch.full((2,), 2.0), atol=0.05)
    _, D_all, _ = render_pixels(scene, depth_required=False, **args)
    assert torch.equal(D_all, depth[[0, 1, 3]])  # the pixel without a reading stays (the mapper's colour term)
    assert render_pixels(scene, depth_required=True, min_rays=3, **args) is None
