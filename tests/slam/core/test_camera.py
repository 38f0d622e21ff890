import torch

from slam.core.camera import backproject, pixel_directions, sample_pixels


def test_pixel_directions_opencv():
    u = torch.tensor([10.0, 20.0])
    v = torch.tensor([5.0, 15.0])
    d = pixel_directions(u, v, fx=10.0, fy=20.0, cx=10.0, cy=5.0)
    assert torch.allclose(d, torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.5, 1.0]]))


def test_backproject_puts_pixels_at_their_depth_along_the_camera_axis():
    u, v = torch.tensor([10.0, 0.0, 4.0]), torch.tensor([5.0, 15.0, 7.0])
    z = torch.tensor([2.0, 0.5, 0.0])
    p = backproject(u, v, z, fx=10.0, fy=20.0, cx=10.0, cy=5.0)
    expected = torch.tensor([[0.0, 0.0, 2.0], [-0.5, 0.25, 0.5], [0.0, 0.0, 0.0]])
    assert torch.allclose(p, expected)
    # projecting back gives the pixels (where z > 0); leading batch dimensions are kept
    assert torch.allclose(10.0 * p[:2, 0] / p[:2, 2] + 10.0, u[:2]) and torch.allclose(20.0 * p[:2, 1] / p[:2, 2] + 5.0, v[:2])
    assert backproject(u.expand(4, 3), v.expand(4, 3), z.expand(4, 3), 10.0, 20.0, 10.0, 5.0).shape == (4, 3, 3)


def test_sample_pixels_bounds_and_determinism():
    v, u = sample_pixels(100, 120, 1000, 10, 20, torch.Generator().manual_seed(1))
    assert v.min() >= 10 and v.max() < 90 and u.min() >= 20 and u.max() < 100
    v2, u2 = sample_pixels(100, 120, 1000, 10, 20, torch.Generator().manual_seed(1))
    assert torch.equal(v, v2) and torch.equal(u, u2)
