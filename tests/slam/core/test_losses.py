import torch

from slam.core.losses import LossWeights, color_loss, depth_loss, sdf_losses, total_loss, tracking_inliers


def test_sdf_losses_regions_hand_computed():
    T = 0.1
    D = torch.tensor([1.0])
    z = torch.tensor([[0.5, 0.97, 1.0, 1.08, 1.2]])
    s = torch.tensor([[0.5, 0.2, 0.1, -0.5, 0.3]])
    out = sdf_losses(s, z, D, T)
    # front: z < 0.9 -> only 0.5: (0.5 - 1)^2
    assert torch.isclose(out["fs"], torch.tensor(0.25))
    # centre |z - D| < 0.04: 0.97 and 1.0 -> (0.97 + 0.02 - 1)^2 = 1e-4, (1.0 + 0.01 - 1)^2 = 1e-4
    assert torch.isclose(out["center"], torch.tensor(1e-4), atol=1e-9)
    # tail: 1.08 (|.08| <= .1 and not centre): (1.08 - 0.05 - 1)^2 = 9e-4 ; 1.2 is behind -> no loss
    assert torch.isclose(out["tail"], torch.tensor(9e-4), atol=1e-9)


def test_sdf_losses_are_pooled_over_points():
    T = 0.1
    D = torch.tensor([1.0, 1.0])
    z = torch.tensor([[0.1, 0.2], [0.3, 2.0]])
    s = torch.tensor([[0.0, 0.0], [1.0, 0.0]])
    out = sdf_losses(s, z, D, T)
    # three front points pooled: (1 + 1 + 0) / 3 (a per-ray mean would give (1 + 0) / 2)
    assert torch.isclose(out["fs"], torch.tensor(2.0 / 3.0))
    assert out["center"] == 0 and out["tail"] == 0


def test_depth_and_color_losses_are_squared():
    assert torch.isclose(depth_loss(torch.tensor([1.0, 2.0]), torch.tensor([1.5, 2.0])), torch.tensor(0.125))
    c = color_loss(torch.zeros(2, 3), torch.tensor([[1.0, 0, 0], [0, 0, 0]]))
    assert torch.isclose(c, torch.tensor(1.0 / 6.0))


def test_total_loss_weights_and_mask():
    T = 0.1
    D = torch.tensor([1.0, 0.0])
    z = torch.tensor([[0.5, 1.0], [0.5, 1.0]])
    s = torch.tensor([[0.0, 0.0], [0.0, 0.0]])
    rd = torch.tensor([0.8, 0.3])
    rc = torch.zeros(2, 3)
    C = torch.ones(2, 3)
    w = LossWeights(fs=2.0, center=3.0, tail=4.0, depth=5.0, color=7.0)
    loss, parts = total_loss(s, z, rd, rc, D, C, T, w)
    # ray 1 has no depth: excluded from SDF and depth terms, kept for colour
    assert abs(parts["fs"] - 1.0) < 1e-6 and abs(parts["center"]) < 1e-9
    assert abs(parts["depth"] - 0.04) < 1e-6 and abs(parts["color"] - 1.0) < 1e-6
    assert torch.isclose(loss, torch.tensor(2.0 * 1.0 + 5.0 * 0.04 + 7.0 * 1.0))


def test_tracking_outliers():
    D = torch.ones(10)
    rd = torch.ones(10) + 0.01
    rd[3] = 5.0
    keep = tracking_inliers(rd, D, 10.0)
    assert keep.sum() == 9 and not keep[3]


def _five_term_sum(s, z, rd, rc, D, C, T, w):
    """``total_loss`` as it was written before the terms were registered: the reference for bit identity."""
    m = D > 0
    parts = sdf_losses(s[m], z[m], D[m], T)
    parts["depth"] = depth_loss(rd[m], D[m])
    parts["color"] = color_loss(rc, C)
    return (w.fs * parts["fs"] + w.center * parts["center"] + w.tail * parts["tail"] + w.depth * parts["depth"]
            + w.color * parts["color"])


def test_total_loss_over_the_registry_is_bit_identical_to_the_five_term_sum():
    g = torch.Generator().manual_seed(1)
    D = torch.rand(64, generator=g) * 3 + 0.3
    D[::6] = 0.0
    z = D[:, None] + (torch.rand(64, 20, generator=g) - 0.6) * 0.5
    C = torch.rand(64, 3, generator=g)
    for w in (LossWeights(fs=10.0, center=200.0, tail=50.0, depth=1.0, color=5.0),
              LossWeights(fs=5.0, center=200.0, tail=10.0, depth=0.1, color=5.0),
              LossWeights(fs=0.0, center=200.0, tail=0.0, depth=1.0, color=0.0)):
        inputs = [torch.tanh(torch.randn(64, 20, generator=g)).requires_grad_(),
                  (D + 0.1 * torch.randn(64, generator=g)).requires_grad_(),
                  torch.rand(64, 3, generator=g).requires_grad_()]
        s, rd, rc = inputs
        new, parts = total_loss(s, z, rd, rc, D, C, 0.1, w)
        old = _five_term_sum(s, z, rd, rc, D, C, 0.1, w)
        assert torch.equal(new, old) and list(parts) == ["fs", "center", "tail", "depth", "color"]
        for a, b in zip(torch.autograd.grad(new, inputs), torch.autograd.grad(old, inputs)):
            assert torch.equal(a, b)


def test_a_zero_weight_still_adds_its_term():
    """As before the registry: a NaN term makes the loss NaN even at weight 0 (0 * NaN)."""
    D = torch.tensor([1.0])
    z = torch.tensor([[0.5, 1.0]])
    s = torch.tensor([[0.0, float("nan")]])
    w = LossWeights(fs=1.0, center=0.0, tail=0.0, depth=0.0, color=0.0)
    loss, _ = total_loss(s, z, torch.tensor([1.0]), torch.zeros(1, 3), D, torch.zeros(1, 3), 0.1, w)
    assert torch.isnan(loss)
