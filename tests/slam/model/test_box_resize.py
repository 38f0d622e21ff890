"""Growing the scene's box: the learned map is copied, not resampled, and answers as before; a saved map of the old
size grows the same way; a fresh scene takes a grown map's shape before loading it."""

import pytest
import torch

import tdfields
from tdfields.kernels.dispatch import use_backend
from slam.config import load_config
from slam.model.box_resize import apply_growth, load_scene_state, pad_state, plan_growth
from slam.model.scene import SceneModel, scene_aabb, scene_size

BOUND = "bound=[[-1,1],[-0.5,1],[0,1.5]]"


def _scene(representation: str) -> SceneModel:
    cfg = load_config("synthetic", [BOUND, f"representation={representation}"], profile="quality")
    torch.manual_seed(0)
    scene = SceneModel(cfg, scene_aabb(cfg.scene.bound, cfg.scene.bound_dividable))
    with torch.no_grad():  # a map that is not its initialisation: every sample its own value
        for p in scene.parameters():
            p.copy_(torch.randn_like(p) * 0.3)
    return scene


def _query(scene, points):
    with torch.no_grad():
        return scene.sdf(points), scene.rgb(points)


@pytest.mark.parametrize("representation", ["lrslam", "eslam"])
def test_growth_copies_the_learned_map_and_it_answers_as_before(representation):
    scene = _scene(representation)
    box = scene.aabb.clone()
    inside = box[:, 0] + torch.rand(3000, 3) * (box[:, 1] - box[:, 0])
    sdf, rgb = _query(scene, inside)
    with tdfields.frozen(scene):  # the Six-axis plane cache of the old size lives and dies inside the block
        frozen_sdf, _ = _query(scene, inside)
    old = {name: t.clone() for name, t in scene.state_dict().items()}
    old_levels = {n: (m.grid_shape, m.aabb.clone()) for n, m in scene.named_modules() if isinstance(m, tdfields.Field)}
    params = scene_size(scene)
    pads = plan_growth(scene, (0.48, 0.0, 0.24), (0.0, 0.72, 0.0))
    apply_growth(scene, pads)

    torch.testing.assert_close(scene.aabb, box + torch.tensor([[-0.48, 0.0], [0.0, 0.72], [-0.24, 0.0]]))
    for name, (shape, level_box) in old_levels.items():
        level = scene.get_submodule(name)
        pad = pads.levels[name]
        assert level.grid_shape == tuple(n + lo + hi for n, lo, hi in zip(shape, pad.lower, pad.upper))
        assert (level.aabb[:, 0] <= scene.aabb[:, 0]).all() and (level.aabb[:, 1] >= scene.aabb[:, 1]).all()
        for factor, spec in level.factor_specs().items():  # the old samples, bit for bit
            inner = (*(slice(pad.lower[a], pad.lower[a] + shape[a]) for a in spec.axes), slice(None))
            assert torch.equal(level.factors[factor].detach()[inner], old[f"{name}.factors.{factor}"])
    # the same function inside the old box (float32 rounding of the grown boxes only), frozen or not
    new_sdf, new_rgb = _query(scene, inside)
    torch.testing.assert_close(new_sdf, sdf, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(new_rgb, rgb, rtol=1e-4, atol=1e-5)
    with tdfields.frozen(scene):
        torch.testing.assert_close(_query(scene, inside)[0], frozen_sdf, rtol=1e-4, atol=1e-5)
    with use_backend("torch"):  # the fused kernels take the new shapes from the tensors: the reference agrees
        torch.testing.assert_close(_query(scene, inside)[0], new_sdf, rtol=1e-5, atol=1e-6)
    assert scene_size(scene)[0] > params[0] and scene_size(scene)[1] > params[1]

    # a state_dict of the old size grows to the grown scene's, exactly
    grown = pad_state(old, pads)
    assert grown.keys() == scene.state_dict().keys()
    assert all(torch.equal(grown[k], v) for k, v in scene.state_dict().items())

    # a fresh scene of the first size takes the grown map's shape, then loads it
    fresh = _scene(representation)
    load_scene_state(fresh, grown)
    assert all(torch.equal(a, b) for a, b in zip(_query(fresh, inside), _query(scene, inside)))
