import pytest
import torch

from slam.config import REPRESENTATIONS, load_config
from slam.rendering import render_rays
from slam.scene import SceneModel, parameter_counts, scene_aabb
from slam.system import auto_bound


@pytest.mark.parametrize("rep", REPRESENTATIONS)
def test_every_representation_builds_and_renders(rep):
    cfg = load_config("synthetic", [f"representation={rep}", "bound=[[0,1],[0,1],[0,1]]"])
    torch.manual_seed(0)
    model = SceneModel(cfg, scene_aabb(cfg.scene.bound, 0.24))
    counts = parameter_counts(model)
    assert counts["total"] == sum(p.numel() for p in model.parameters())
    assert counts["decoders"] == 1329 + 1363 + 1
    o = torch.full((8, 3), 0.5)
    d = torch.tensor([[0.0, 0.0, 1.0]]).expand(8, 3)
    out = render_rays(o, d, torch.full((8,), 0.3), model.sdf, model.rgb, model.beta, 0.06, 8, 4, model.aabb)
    assert out.depth.shape == (8,) and torch.isfinite(out.color).all()
    out.depth.sum().backward()
    assert model.fields["geometry"].levels[1] is not None


def test_tracking_freezes_scene_gradients():
    from tdfields import frozen

    cfg = load_config("synthetic", ["bound=[[0,1],[0,1],[0,1]]"])
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
