"""The Levenberg-Marquardt tracker (slam/engine/gauss_newton.py): its normal equations are the loss's derivatives,
and it converges from known offsets in a handful of evaluations where Adam takes many iterations."""

import copy
import math

import pytest
import torch

from slam.config import load_config
from tests.slam.conftest import TINY


@pytest.fixture(scope="module")
def mapped(tiny_seq):
    """A tiny room mapped over 6 frames (sequential mode), and frame 5 with its ground-truth pose."""
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=false", "mapping.iters=10",
                                    "tracking.pixels=300", "rendering.color_cutoff=0"])
    s = SLAM(cfg, load_data(cfg))
    for k in range(6):
        s.step(k)
    s.finish()
    frame = s.frames.get(5)
    yield s, cfg, frame
    s.close()


def test_the_normal_equations_are_the_derivatives_of_the_loss(mapped):
    """``J^T W r`` is half the gradient of the loss in the pose's tangent (checked by central differences of the
    same deterministic objective along each of the six directions; steps of 1e-4: the composited depth is sharp
    enough that 1e-3 is outside its linear range)."""
    import tdfields
    from slam.core.pose import exp_se3
    from slam.engine import gauss_newton as gn

    s, cfg, frame = mapped
    T = s.gt[5].clone()
    with tdfields.frozen(s.scene):
        rays = gn._draw_rays(s.scene, frame.color, frame.depth, s.intr, T, cfg, torch.Generator().manual_seed(3))
        _, _, (H, b) = gn._evaluate(s.scene, T, rays, cfg, jacobian=True)
        h = 1e-4
        numeric = []
        for j in range(6):
            e = torch.zeros(6)
            e[j] = h
            plus = gn._evaluate(s.scene, exp_se3(e) @ T, rays, cfg, jacobian=False)[0]
            minus = gn._evaluate(s.scene, exp_se3(-e) @ T, rays, cfg, jacobian=False)[0]
            numeric.append((plus - minus) / (2 * h))
    numeric = torch.tensor(numeric, dtype=torch.float64)
    assert torch.allclose(2 * b, numeric, rtol=0.05, atol=0.02 * float(numeric.abs().max()))
    assert bool((torch.linalg.eigvalsh(H) > 0).all())  # six observable directions


def test_it_converges_from_a_known_offset_in_a_handful_of_evaluations(mapped):
    """From an offset of a few cm and degrees, 8 Levenberg-Marquardt evaluations take the camera at least 5x closer
    to where it settles with a long budget (the tiny room's optimum is shallow: benchmarks/gn_convergence.py
    measures iterations to 1 mm / 0.1 deg on the full room), and closer than 8 Adam iterations do."""
    from slam.core.pose import exp_se3, matrix_to_pose
    from slam.engine.tracker import track_frame
    from slam.engine.tracking_guard import motion

    s, cfg, frame = mapped
    offset_cm, offset_deg = 3.0, 3.0
    xi = torch.tensor([math.radians(offset_deg) / math.sqrt(3)] * 3 + [offset_cm / 100 / math.sqrt(3)] * 3)
    start = matrix_to_pose(exp_se3(xi) @ s.gt[5])
    gn_cfg = copy.deepcopy(cfg)
    gn_cfg.tracking.optimizer = "gauss_newton"
    gn_cfg.tracking.gn_step_m, gn_cfg.tracking.gn_step_deg = 1e-6, 1e-5

    def run(c, iters):
        return track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0),
                           iters=iters)

    settled = run(gn_cfg, 40)
    short = run(gn_cfg, 8)
    d0, deg0 = motion(settled.pose, start)
    d, deg = motion(settled.pose, short.pose)
    assert settled.ok and short.ok and d < d0 / 5 and deg < deg0 / 5, (d0, deg0, d, deg)
    adam = run(cfg, 8)
    assert motion(settled.pose, adam.pose)[0] > d


def test_a_second_round_redraws_the_rays_at_the_pose_the_first_reached(mapped, monkeypatch):
    from slam.core.pose import exp_se3, matrix_to_pose, pose_to_matrix
    from slam.engine import gauss_newton as gn
    from slam.engine.tracker import track_frame
    from slam.engine.tracking_guard import motion

    s, cfg, frame = mapped
    xi = torch.tensor([math.radians(2.0) / math.sqrt(3)] * 3 + [0.02 / math.sqrt(3)] * 3)
    start = matrix_to_pose(exp_se3(xi) @ s.gt[5])
    c = copy.deepcopy(cfg)
    c.tracking.optimizer = "gauss_newton"
    drawn_at = []
    draw = gn._draw_rays
    monkeypatch.setattr(gn, "_draw_rays", lambda *a: drawn_at.append(a[4].clone()) or draw(*a))
    one = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0))
    c.tracking.gn_rounds = 2
    drawn_at.clear()
    two = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0))
    assert len(drawn_at) == 2 and torch.allclose(drawn_at[0], pose_to_matrix(start))
    assert torch.allclose(drawn_at[1], pose_to_matrix(one.pose), atol=1e-5)  # round 2 starts where round 1 ended
    assert two.ok and two.iters > one.iters
    c.tracking.gn_rounds, c.tracking.gn_step_m, c.tracking.gn_step_deg = 1, 1e-6, 1e-5
    settled = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0), 40)
    # another pixel set is another objective: on the tiny map its optimum lies about 2 cm from the first one's
    assert motion(two.pose, settled.pose)[0] < motion(start, settled.pose)[0] / 3


def test_the_outlier_rule_inside_an_evaluation_gives_the_normal_equations_of_the_inliers_alone(mapped):
    """``_evaluate(..., outliers=True)`` renders every ray, drops the outliers of its own rendering and returns the
    loss and normal equations of the rest: the same as evaluating the kept rays on their own."""
    import tdfields
    from slam.core.losses import tracking_inliers
    from slam.engine import gauss_newton as gn

    s, cfg, frame = mapped
    T = s.gt[5].clone()
    with tdfields.frozen(s.scene):
        rays = gn._draw_rays(s.scene, frame.color, frame.depth, s.intr, T, cfg, torch.Generator().manual_seed(4))
        D = rays.D.clone()
        D[::5] += 0.5  # every fifth measured depth half a metre off: outliers of the rendering
        bad = gn._Rays(rays.dirs_cam, rays.z, D, rays.C)
        loss, rendered, (H, b), share = gn._evaluate(s.scene, T, bad, cfg, jacobian=True, outliers=True)
        keep = tracking_inliers(rendered, D, cfg.tracking.outlier_factor)
        assert 0.5 < float(keep.float().mean()) < 1.0  # some, not most, are outliers
        alone = gn._Rays(rays.dirs_cam[keep], rays.z[keep], D[keep], rays.C[keep])
        loss2, _, (H2, b2) = gn._evaluate(s.scene, T, alone, cfg, jacobian=True)
    assert share == pytest.approx(float(keep.float().mean()))
    assert loss == pytest.approx(loss2, rel=1e-5)
    assert torch.allclose(H, H2, rtol=1e-4, atol=1e-8 * float(H2.abs().max()))
    assert torch.allclose(b, b2, rtol=1e-4, atol=1e-6 * float(b2.abs().max()))


def test_incremental_gauss_newton_draws_fresh_pixels_at_each_pose_and_converges(mapped, monkeypatch):
    """``gn_draw: every_step``: every evaluation draws its own pixels at the pose reached so far. From 3 degrees
    and 3 cm off (9 cm at the camera centre) 8 evaluations take the camera at least 2x closer to the ground truth,
    and closer than Levenberg-Marquardt on one draw settles (40 evaluations): on the tiny map one draw's optimum
    lies centimetres from another's, and the summed draws average that out."""
    from slam.core.pose import exp_se3, matrix_to_pose, pose_to_matrix
    from slam.engine import gauss_newton as gn
    from slam.engine.tracker import track_frame
    from slam.engine.tracking_guard import motion

    s, cfg, frame = mapped
    xi = torch.tensor([math.radians(3.0) / math.sqrt(3)] * 3 + [0.03 / math.sqrt(3)] * 3)
    start = matrix_to_pose(exp_se3(xi) @ s.gt[5])
    c = copy.deepcopy(cfg)
    c.tracking.optimizer, c.tracking.gn_draw, c.tracking.gn_iters = "gauss_newton", "every_step", 8
    drawn_at = []
    draw = gn._draw_rays
    monkeypatch.setattr(gn, "_draw_rays", lambda *a: drawn_at.append(a[4].clone()) or draw(*a))
    r = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0))
    assert r.ok and r.iters == len(drawn_at) and 2 <= r.iters <= 8
    assert torch.allclose(drawn_at[0], pose_to_matrix(start))
    assert not torch.allclose(drawn_at[1], drawn_at[0])  # the second draw is at the pose the first step reached
    gt = matrix_to_pose(s.gt[5])
    d0, deg0 = motion(start, gt)
    d, deg = motion(r.pose, gt)
    assert d < d0 / 2 and deg < deg0 / 2, (d0, deg0, d, deg)
    c.tracking.gn_draw, c.tracking.gn_step_m, c.tracking.gn_step_deg = "once", 1e-6, 1e-5
    one = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0), 40)
    d1, deg1 = motion(one.pose, gt)
    assert d < d1 and deg < deg1, (d, deg, d1, deg1)
