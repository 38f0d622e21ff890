import pytest
import torch

from slam.config import REPRESENTATIONS, load_config
from slam.core.rendering import render_rays
from slam.model.scene import SceneModel, parameter_counts, scene_aabb
from slam.engine.setup import auto_bound


def _rays(dtype=torch.float32):
    o = torch.tensor([[0.5, 0.5, 0.05]], dtype=dtype).expand(8, 3) + torch.linspace(-0.3, 0.3, 8, dtype=dtype)[:, None]
    d = torch.tensor([[0.1, -0.05, 1.0]], dtype=dtype).expand(8, 3)
    return o, d, torch.full((8,), 0.3, dtype=dtype)


def _depth(model, rays) -> torch.Tensor:
    o, d, D = rays
    out = render_rays(o, d, D, model.sdf, model.rgb, model.beta, 0.06, 8, 4, model.aabb, perturb=False)
    return out.depth.sum()


@pytest.mark.parametrize("rep", REPRESENTATIONS)
def test_every_representation_builds_and_renders(rep):
    """Each representation renders, and the rendered depth's gradient reaches exactly the parameters it depends on
    (geometry, at every level, the SDF decoder and beta; never appearance or the colour decoder) with the values
    central differences give."""
    cfg = load_config("synthetic", [f"representation={rep}", "bound=[[0,1],[0,1],[0,1]]"], profile="quality")
    torch.manual_seed(0)
    model = SceneModel(cfg, scene_aabb(cfg.scene.bound, 0.24))
    counts = parameter_counts(model)
    assert counts["total"] == sum(p.numel() for p in model.parameters())
    assert counts["decoders"] == 1329 + 1363 + 1
    assert counts["geometry"] == model.fields["geometry"].num_parameters() > 0
    model = model.double()  # float64: the finite differences below resolve 1e-7 relative changes
    rays = _rays(torch.float64)
    depth = _depth(model, rays)
    assert torch.isfinite(depth)
    depth.backward()
    grads = {name: p.grad for name, p in model.named_parameters()}
    assert {n.split(".")[0] for n in grads} == {"fields", "sdf_decoder", "rgb_decoder", "beta"}
    for name, g in grads.items():
        if name.startswith(("fields.appearance.", "rgb_decoder.")):
            assert g is None, name
        else:
            assert g is not None and bool(g.abs().sum() > 0), name
    assert {n.split(".")[3] for n in grads if n.startswith("fields.geometry.")} == {"0", "1"}  # both levels
    fine = next(p for n, p in model.named_parameters() if n.startswith("fields.geometry.levels.1."))
    checks = [(model.beta, ()), (fine, tuple(int(i) for i in (fine.grad.abs() == fine.grad.abs().max()).nonzero()[0]))]
    with torch.no_grad():
        for p, idx in checks:
            eps = 1e-6 * max(1.0, abs(float(p[idx])))
            p[idx] += eps
            up = float(_depth(model, rays))
            p[idx] -= 2 * eps
            down = float(_depth(model, rays))
            p[idx] += eps
            assert (up - down) / (2 * eps) == pytest.approx(float(p.grad[idx]), rel=1e-5, abs=1e-9)


def test_tracking_freezes_scene_gradients():
    from tdfields import frozen

    cfg = load_config("synthetic", ["bound=[[0,1],[0,1],[0,1]]"], profile="quality")
    model = SceneModel(cfg, scene_aabb(cfg.scene.bound, 0.24))
    x = torch.rand(10, 3, requires_grad=True)
    with frozen(model):
        model.sdf(x).sum().backward()
    assert x.grad is not None
    assert all(p.grad is None for p in model.parameters())
    assert all(p.requires_grad for p in model.parameters())


def test_auto_bound_is_a_cube_around_the_first_camera():
    depth = torch.zeros(10, 10)
    depth[2:8, 2:8] = 2.0
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    b = auto_bound([depth], c2w, 99.0, 0.5)
    assert b == [[-1.5, 3.5], [-0.5, 4.5], [0.5, 5.5]]
