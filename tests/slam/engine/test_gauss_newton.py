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
                                    "tracking.pixels=300", "rendering.color_cutoff=0"], profile="quality")
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
        _, _, (H, b) = gn._evaluate(s.scene, T, rays, cfg, "hessian")
        h = 1e-4
        numeric = []
        for j in range(6):
            e = torch.zeros(6)
            e[j] = h
            plus = gn._evaluate(s.scene, exp_se3(e) @ T, rays, cfg)[0]
            minus = gn._evaluate(s.scene, exp_se3(-e) @ T, rays, cfg)[0]
            numeric.append((plus - minus) / (2 * h))
    numeric = torch.tensor(numeric, dtype=torch.float64)
    assert torch.allclose(2 * b, numeric, rtol=0.05, atol=0.02 * float(numeric.abs().max()))
    assert bool((torch.linalg.eigvalsh(H) > 0).all())  # six observable directions


def _residuals(scene, T, rays, cfg):
    """The tracking loss's residuals and weights as docs/slam.md defines them (the oracle for ``H``): free space
    ``s - 1`` (z < D - T), the band ``z + s T - D`` (centre |z - D| < 0.4 T, tail the rest of |z - D| <= T), depth
    ``d - D`` and colour ``c - C``, each term a mean over its residuals times its weight."""
    from slam.core.losses import sdf_regions
    from slam.engine import gauss_newton as gn

    T_, wt = cfg.scene.truncation, cfg.tracking.weights
    s, _, _, _, _, depth, color = gn._render(scene, gn._points(T, rays), rays, 0.0, False)
    front, center, tail = sdf_regions(rays.z, rays.D, T_)
    band = rays.z + s * T_ - rays.D[:, None]
    parts = [(s[front] - 1.0, wt.fs), (band[center], wt.center), (band[tail], wt.tail),
             (depth - rays.D, wt.depth), ((color - rays.C).reshape(-1), wt.color)]
    r = torch.cat([p for p, _ in parts]).double()
    w = torch.cat([torch.full((len(p),), lam / max(len(p), 1), dtype=torch.float64) for p, lam in parts])
    return r.detach(), w


def test_the_normal_equations_matrix_is_the_residuals_jacobian(mapped):
    """``H = J^T W J`` with ``J`` the residuals' central differences in the six tangent directions (the assembly
    that folds every region into one product against the definition of each residual)."""
    import tdfields
    from slam.core.pose import exp_se3
    from slam.engine import gauss_newton as gn

    s, cfg, frame = mapped
    T = s.gt[5].clone()
    with tdfields.frozen(s.scene), torch.no_grad():
        rays = gn._draw_rays(s.scene, frame.color, frame.depth, s.intr, T, cfg, torch.Generator().manual_seed(3))
        r0, w = _residuals(s.scene, T, rays, cfg)
        h, cols = 1e-4, []
        for j in range(6):
            e = torch.zeros(6)
            e[j] = h
            cols.append((_residuals(s.scene, exp_se3(e) @ T, rays, cfg)[0]
                         - _residuals(s.scene, exp_se3(-e) @ T, rays, cfg)[0]) / (2 * h))
    with tdfields.frozen(s.scene):
        _, _, (H, b) = gn._evaluate(s.scene, T, rays, cfg, "hessian")
    J = torch.stack(cols, 1)
    H_fd = J.T @ (w[:, None] * J)
    torch.testing.assert_close(H, H_fd, rtol=0.05, atol=0.02 * float(H_fd.abs().max()))
    torch.testing.assert_close(b, J.T @ (w * r0), rtol=0.05, atol=0.02 * float(b.abs().max()))


@pytest.mark.parametrize("fused", [False, True])
def test_the_gradient_alone_is_the_normal_equations_right_hand_side(mapped, fused):
    """``tracking.gn_hessian: first``'s one backward pass gives the ``b`` of the full normal equations."""
    import tdfields
    from slam.engine import gauss_newton as gn

    s, cfg, frame = mapped
    c = copy.deepcopy(cfg)
    c.rendering.fused, c.rendering.color_cutoff = fused, 1e-3
    T = s.gt[5].clone()
    with tdfields.frozen(s.scene):
        rays = gn._draw_rays(s.scene, frame.color, frame.depth, s.intr, T, c, torch.Generator().manual_seed(3))
        loss_h, _, (_, b_h) = gn._evaluate(s.scene, T, rays, c, "hessian")
        loss_g, _, (H_g, b_g) = gn._evaluate(s.scene, T, rays, c, "gradient")
    assert loss_g == loss_h and H_g is None
    torch.testing.assert_close(b_g, b_h, rtol=1e-4, atol=1e-6 * float(b_h.abs().max()))


def test_the_evaluations_that_end_a_round_skip_the_jacobian_and_change_nothing(mapped, monkeypatch):
    """A round's last evaluation (a small step, or the last allowed) asks for the loss alone; computing the full
    normal equations there too ends at the same pose, bit for bit."""
    from slam.core.pose import exp_se3, matrix_to_pose
    from slam.engine import gauss_newton as gn
    from slam.engine.tracker import track_frame

    s, cfg, frame = mapped
    xi = torch.tensor([math.radians(2.0) / math.sqrt(3)] * 3 + [0.02 / math.sqrt(3)] * 3)
    start = matrix_to_pose(exp_se3(xi) @ s.gt[5])
    c = copy.deepcopy(cfg)
    c.tracking.optimizer = "gauss_newton"
    evaluate, needs = gn._evaluate, []
    monkeypatch.setattr(gn, "_evaluate", lambda *a: needs.append(a[4] if len(a) > 4 else "loss") or evaluate(*a))
    skipped = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0), 6)
    assert needs[0] == "loss" and needs[1] == "hessian" and needs[-1] == "loss" and len(needs) == skipped.iters
    assert needs[2:-1] == ["hessian"] * (len(needs) - 3)
    monkeypatch.setattr(gn, "_evaluate", lambda *a: evaluate(*a[:4], "hessian"))
    full = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0), 6)
    assert torch.equal(skipped.pose, full.pose) and skipped.loss == full.loss and skipped.iters == full.iters


def test_a_step_predicted_to_lower_the_loss_by_little_ends_the_round(mapped, monkeypatch):
    """``gn_min_decrease``: a step whose decrease the normal equations' quadratic model predicts under that share of
    the loss ends the round, its pose evaluated for the loss alone; it is the step the round without the rule takes
    first, from 2 cm / 2 degrees off towards the truth."""
    from slam.core.pose import exp_se3, matrix_to_pose
    from slam.engine import gauss_newton as gn
    from slam.engine.tracker import track_frame
    from slam.engine.tracking_guard import motion

    s, cfg, frame = mapped
    xi = torch.tensor([math.radians(2.0) / math.sqrt(3)] * 3 + [0.02 / math.sqrt(3)] * 3)
    start = matrix_to_pose(exp_se3(xi) @ s.gt[5])
    c = copy.deepcopy(cfg)
    c.tracking.optimizer, c.tracking.gn_damping = "gauss_newton", 0.0
    evaluate, seen = gn._evaluate, []
    monkeypatch.setattr(gn, "_evaluate", lambda *a: seen.append((a[4] if len(a) > 4 else "loss")) or evaluate(*a))

    def run(decrease, iters):
        c.tracking.gn_min_decrease = decrease
        seen.clear()
        r = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0), iters)
        return r, list(seen)

    one, _ = run(0.0, 3)  # one step, then the loss there
    stopped, stopped_seen = run(1.0, 8)  # every step is under the whole loss
    assert stopped_seen == ["loss", "hessian", "loss"] and stopped.iters == 3
    assert torch.equal(stopped.pose, one.pose) and stopped.loss == one.loss and stopped.message == "converged"
    truth = matrix_to_pose(s.gt[5])
    assert motion(stopped.pose, truth)[0] < motion(start, truth)[0]
    longer, _ = run(0.0, 8)
    assert longer.iters > 3  # without the rule the same start takes more steps


def test_the_fused_render_tail_gives_the_reference_normal_equations(mapped):
    import tdfields
    from slam.engine import gauss_newton as gn

    s, cfg, frame = mapped
    T = s.gt[5].clone()
    out = {}
    for fused in (False, True):
        c = copy.deepcopy(cfg)
        c.rendering.fused = fused
        with tdfields.frozen(s.scene):
            rays = gn._draw_rays(s.scene, frame.color, frame.depth, s.intr, T, c, torch.Generator().manual_seed(3))
            out[fused] = gn._evaluate(s.scene, T, rays, c, "hessian")
    (loss0, _, (H0, b0)), (loss1, _, (H1, b1)) = out[False], out[True]
    assert loss1 == pytest.approx(loss0, rel=1e-5)
    torch.testing.assert_close(H1, H0, rtol=1e-4, atol=1e-6 * float(H0.abs().max()))
    torch.testing.assert_close(b1, b0, rtol=1e-4, atol=1e-5 * float(b0.abs().max()))


@pytest.mark.parametrize("hessian", ["every", "first"])
def test_it_converges_from_a_known_offset_in_a_handful_of_evaluations(mapped, hessian):
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
    gn_cfg.tracking.gn_hessian = hessian

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


def test_the_prior_holds_the_pose_towards_its_start(mapped):
    """``tracking.gn_prior``: the same draw, a stronger prior, a pose closer to the start (and a very strong one
    leaves it within a millimetre and 0.05 degree of it); the reported loss is the data term's, so the unregularised
    solve reports the lowest."""
    from slam.core.pose import exp_se3, matrix_to_pose
    from slam.engine.tracker import track_frame
    from slam.engine.tracking_guard import motion

    s, cfg, frame = mapped
    xi = torch.tensor([math.radians(2.0) / math.sqrt(3)] * 3 + [0.02 / math.sqrt(3)] * 3)
    start = matrix_to_pose(exp_se3(xi) @ s.gt[5])
    c = copy.deepcopy(cfg)
    c.tracking.optimizer = "gauss_newton"
    out = {}
    for kappa in (0.0, 0.3, 1e4):
        c.tracking.gn_prior = kappa
        out[kappa] = track_frame(s.scene, frame.color, frame.depth, s.intr, start, c, torch.Generator().manual_seed(0))
    moved = {k: motion(r.pose, start) for k, r in out.items()}
    assert all(r.ok for r in out.values())
    assert moved[0.3][0] < moved[0.0][0] and moved[0.3][1] < moved[0.0][1], moved
    assert moved[1e4][0] < 1e-3 and moved[1e4][1] < 0.05, moved
    assert out[0.0].loss <= out[0.3].loss <= out[1e4].loss


def test_a_non_finite_depth_or_too_few_inliers_is_refused_as_the_adam_tracker_refuses_them(mapped, monkeypatch):
    """A map with NaN in part of its geometry (some rays render NaN) and a frame whose rays are all outliers: the
    result is not ok and says why, as Adam's is, where 20b7b9c divided by zero rays (ZeroDivisionError)."""
    import slam.engine.gauss_newton as gauss_newton

    s, cfg, frame = mapped
    gn_cfg = copy.deepcopy(cfg)
    gn_cfg.tracking.optimizer = "gauss_newton"

    def track(scene):
        return gauss_newton.track_frame_gn(scene, frame.color, frame.depth, s.intr, s.state.est[4], gn_cfg,
                                           torch.Generator().manual_seed(0))

    broken = copy.deepcopy(s.scene)
    with torch.no_grad():
        for name, p in broken.named_parameters():
            if name.startswith("fields.geometry"):
                p.view(-1)[: p.numel() // 3] = float("nan")
    res = track(broken)
    assert not res.ok and res.message == "non-finite rendered depth" and torch.equal(res.pose, s.state.est[4])
    real = gauss_newton.tracking_inliers
    monkeypatch.setattr(gauss_newton, "tracking_inliers", lambda *a: real(*a) & False)
    res = track(s.scene)
    assert not res.ok and res.message == "too few inlier rays" and res.inliers == 0.0
