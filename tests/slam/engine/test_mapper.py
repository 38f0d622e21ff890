"""The mapping step guard: a step whose loss or gradient is not finite is skipped, and only that step."""

import copy

import pytest
import torch

import tdfields
import slam.engine.mapper as mapper
from slam.config import load_config
from slam.engine.keyframes import KeyframeStore
from tests.slam.conftest import TINY


@pytest.fixture(scope="module")
def setup(tiny_seq):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "mapping.iters=3"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    for k in range(5):  # a warm map with keyframes, so the call below runs BA too
        s.step(k)
    s.finish()
    frame = s.frames.get(5)
    s.close()
    return cfg, s, frame


def _map(cfg, s, frame, iters):
    scene = copy.deepcopy(s.scene)
    keyframes = KeyframeStore([copy.deepcopy(kf) for kf in s.keyframes.frames])
    c = copy.deepcopy(cfg)
    c.mapping.iters = iters
    gen = torch.Generator().manual_seed(3)
    res = mapper.map_frame(scene, 5, frame.color, frame.depth, s.state.est[-1], s.intr, keyframes, c, gen)
    return scene, keyframes, res


def _same(a, b):
    for (na, pa), (nb, pb) in zip(a.state_dict().items(), b.state_dict().items()):
        assert na == nb and torch.equal(pa, pb), na


def test_a_nan_loss_in_the_last_step_leaves_the_map_as_the_step_before(setup, monkeypatch):
    cfg, s, frame = setup
    ref, ref_kf, ref_res = _map(cfg, s, frame, iters=2)
    real = mapper.total_loss
    calls = {"n": 0}

    def poisoned(*args, **kw):
        calls["n"] += 1
        loss, parts = real(*args, **kw)
        return (loss * float("nan"), parts) if calls["n"] == 3 else (loss, parts)

    monkeypatch.setattr(mapper, "total_loss", poisoned)
    got, got_kf, res = _map(cfg, s, frame, iters=3)
    assert res.ok and res.skipped == 1
    _same(got, ref)
    assert torch.equal(res.pose, ref_res.pose)
    assert all(torch.equal(a.pose, b.pose) for a, b in zip(got_kf.frames, ref_kf.frames))


def test_a_nan_gradient_is_caught_before_the_step(setup, monkeypatch):
    cfg, s, frame = setup
    ref, _, _ = _map(cfg, s, frame, iters=2)
    real = mapper.finite_step
    calls = {"n": 0}

    def with_nan_grad(loss, params):
        calls["n"] += 1
        if calls["n"] == 3:  # a NaN reaches one factor's gradient on the third backward
            g = next(p for p in params if p.grad is not None and p.dim() == 2)
            g.grad[0, 0] = float("nan")
        return real(loss, params)

    monkeypatch.setattr(mapper, "finite_step", with_nan_grad)
    got, _, res = _map(cfg, s, frame, iters=3)
    assert res.skipped == 1
    _same(got, ref)
    assert all(torch.isfinite(p).all() for p in got.parameters())


def test_a_call_with_no_finite_step_reports_failure_and_changes_nothing(setup, monkeypatch):
    cfg, s, frame = setup
    before = copy.deepcopy(s.scene)
    real = mapper.total_loss
    monkeypatch.setattr(mapper, "total_loss", lambda *a, **k: (real(*a, **k)[0] * float("nan"), {}))
    got, _, res = _map(cfg, s, frame, iters=3)
    assert not res.ok and res.skipped == 3
    _same(got, before)


def _groups_seen(cfg, s, frame, monkeypatch, scaling, first=False, index=5, **mapping):
    seen = {}
    real = mapper.adam

    def spy(groups, **kw):
        seen["groups"] = [(g["lr"], list(g["params"])) for g in groups]
        return real(groups, **kw)

    monkeypatch.setattr(mapper, "adam", spy)
    c = copy.deepcopy(cfg)
    c.mapping.lr_scaling = scaling
    for key, value in mapping.items():
        setattr(c.mapping, key, value)
    scene = copy.deepcopy(s.scene)
    gen = torch.Generator().manual_seed(3)
    keyframes = KeyframeStore([copy.deepcopy(kf) for kf in s.keyframes.frames])
    mapper.map_frame(scene, index, frame.color, frame.depth, s.state.est[-1], s.intr, keyframes, c, gen,
                     first=first)
    return scene, seen["groups"]


def test_matched_rates_scale_each_factor_by_its_step_scale_and_nothing_else(setup, monkeypatch):
    cfg, s, frame = setup
    assert cfg.representation == "lrslam"
    scene, groups = _groups_seen(cfg, s, frame, monkeypatch, "matched")
    scales = {}
    for name, value in tdfields.step_scales(s.scene.fields).items():  # the map as the call found it
        scales[id(dict(scene.fields.named_parameters())[name])] = value
    m = cfg.mapping
    by_param = {id(p): lr for lr, ps in groups for p in ps}
    geo = {id(p) for p in scene.fields["geometry"].parameters()}
    for p in scene.fields.parameters():
        base = m.lr_geometry if id(p) in geo else m.lr_appearance
        assert by_param[id(p)] == pytest.approx(base * scales[id(p)], rel=1e-12)
    for p in [*scene.sdf_decoder.parameters(), *scene.rgb_decoder.parameters(), scene.beta]:
        assert by_param[id(p)] == m.lr_decoders
    assert {id(p) for p in scene.parameters()} <= set(by_param)
    # a small product (this map is 5 frames old): CP geometry is scaled up
    assert min(by_param[i] for i in geo) > m.lr_geometry


def test_matched_rates_leave_the_warm_up_at_the_configured_rates(setup, monkeypatch):
    cfg, s, frame = setup
    _, plain = _groups_seen(cfg, s, frame, monkeypatch, "none", first=True)
    _, matched = _groups_seen(cfg, s, frame, monkeypatch, "matched", first=True)
    assert [lr for lr, _ in plain] == [lr for lr, _ in matched]


@pytest.fixture(scope="module")
def eslam_setup(tiny_seq):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "mapping.iters=3", "representation=eslam"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    for k in range(5):
        s.step(k)
    s.finish()
    frame = s.frames.get(5)
    s.close()
    return cfg, s, frame


def test_matched_rates_change_nothing_for_tri_planes(eslam_setup, monkeypatch):
    """Single-factor terms have scale 1.0: ESLAM's mapping call is bit-identical either way."""
    cfg, s, frame = eslam_setup
    plain, _ = _groups_seen(cfg, s, frame, monkeypatch, "none")
    matched, _ = _groups_seen(cfg, s, frame, monkeypatch, "matched")
    _same(plain, matched)


def _calls(cfg, s, frame, state: str, moments=None, adam=None, monkeypatch=None):
    """Two mapping calls of frame 5 (3 iterations each, no BA) from the warm map, the same draws; ``adam``, if
    given, replaces the mapper's optimiser factory. Returns the scene after them."""
    c = copy.deepcopy(cfg)
    c.mapping.optimizer_state = state
    c.mapping.joint_opt = False
    c.mapping.lr_scaling = "none"  # rates fixed from call to call, so one kept Adam is the exact reference
    if adam is not None:
        monkeypatch.setattr(mapper, "adam", adam)
    scene = copy.deepcopy(s.scene)
    keyframes = KeyframeStore([copy.deepcopy(kf) for kf in s.keyframes.frames])
    gen = torch.Generator().manual_seed(3)
    for _ in range(2):
        mapper.map_frame(scene, 5, frame.color, frame.depth, s.state.est[-1], s.intr, keyframes, c, gen,
                         moments=moments)
    return scene


def test_carried_moments_are_one_adam_kept_across_the_calls(setup, monkeypatch):
    """``mapping.optimizer_state: persistent``: the moments a call leaves (its Adam's state per parameter) start
    the next, so two calls move the map exactly as one Adam object kept across both (the reference: the factory spied to
    hand back the first call's optimiser; fixed rates, as a kept Adam keeps its first call's), its step count
    going on (3, then 6); a fresh Adam per call (ESLAM's) moves it differently, and so does a caller that holds no
    moments. With ``lr_scaling: lift`` each call's rates are its own (the moments carry, the rates do not)."""
    cfg, s, frame = setup
    moments = mapper.MapMoments()
    carried = _calls(cfg, s, frame, "persistent", moments)
    assert {float(v["step"]) for v in moments.state.values()} == {6.0}
    kept = {}
    real = mapper.adam

    def one_adam(groups, **kw):
        kept.setdefault("opt", real(groups, **kw))
        return kept["opt"]

    reference = _calls(cfg, s, frame, "per_call", adam=one_adam, monkeypatch=monkeypatch)
    _same(carried, reference)
    monkeypatch.setattr(mapper, "adam", real)
    fresh = _calls(cfg, s, frame, "per_call")
    assert not torch.equal(carried.state_dict()["fields.geometry.levels.0.factors.x"],
                           fresh.state_dict()["fields.geometry.levels.0.factors.x"])
    _same(_calls(cfg, s, frame, "persistent", None), fresh)  # no moments held: nothing carried


def test_the_warm_up_carries_no_moments_and_a_growth_forgets_them(setup):
    """The warm-up's rates are x lr_first_factor: its Adam is not carried; a grown map's factors have other
    shapes, so the worker's moments are reset (the next call starts afresh)."""
    from slam.engine.map_worker import MapWorker

    cfg, s, frame = setup
    c = copy.deepcopy(cfg)
    c.mapping.optimizer_state = "persistent"
    scene = copy.deepcopy(s.scene)
    moments = mapper.MapMoments()
    mapper.map_frame(scene, 5, frame.color, frame.depth, s.state.est[-1], s.intr, KeyframeStore(), c,
                     torch.Generator().manual_seed(3), first=True, moments=moments)
    assert moments.state is None
    worker = MapWorker(scene, KeyframeStore(), c, s.intr, torch.Generator().manual_seed(3), parallel=False)
    worker.moments.state = {"fields.geometry.levels.0.factors.x": {}}
    worker.grow(torch.full((3,), 0.1), torch.zeros(3))
    assert worker.moments.state is None
    worker.close()


def test_carried_moments_that_do_not_fit_the_scene_are_refused_when_a_checkpoint_is_loaded(setup):
    """A worker restored with moments of a parameter the scene lacks, or of another shape, raises at once (the
    system turns it into the config error), not at the first mapping call on the mapper's thread."""
    from slam.engine.map_worker import MapWorker

    cfg, s, frame = setup
    c = copy.deepcopy(cfg)
    c.mapping.optimizer_state = "persistent"
    scene = copy.deepcopy(s.scene)
    moments = mapper.MapMoments()
    mapper.map_frame(scene, 5, frame.color, frame.depth, s.state.est[-1], s.intr,
                     KeyframeStore([copy.deepcopy(kf) for kf in s.keyframes.frames]), c,
                     torch.Generator().manual_seed(3), moments=moments)
    worker = MapWorker(scene, KeyframeStore(), c, s.intr, torch.Generator().manual_seed(3), parallel=False)
    state = worker.state_dict()
    state["moments"] = moments.cpu_state()
    worker.load_state_dict(state)  # the moments as saved fit
    name = "fields.geometry.levels.0.factors.x"
    wrong_shape = copy.deepcopy(state)
    wrong_shape["moments"][name]["exp_avg_sq"] = torch.zeros(3, 3)
    with pytest.raises(RuntimeError, match=f"moments of {name} \\(exp_avg_sq\\) have shape \\(3, 3\\)"):
        worker.load_state_dict(wrong_shape)
    stray = copy.deepcopy(state)
    stray["moments"]["fields.nothing"] = stray["moments"][name]
    with pytest.raises(RuntimeError, match="fields.nothing, which this scene has no parameter of"):
        worker.load_state_dict(stray)
    worker.close()


def test_rays_without_depth_are_mapped_on_colour_or_skipped_by_the_config(setup, monkeypatch):
    import slam.core.rendering as rendering

    cfg, s, frame = setup
    real = rendering.render_rays
    depth = frame.depth.clone()
    depth[:, : depth.shape[1] // 2] = 0.0  # the current frame's left half has no depth reading
    seen = {}
    for rule in ("render", "skip"):
        seen[rule] = []

        def spy(origins, dirs, d, *args, _into=seen[rule], **kwargs):
            _into.append(d.detach().clone())
            return real(origins, dirs, d, *args, **kwargs)

        monkeypatch.setattr(rendering, "render_rays", spy)
        c = copy.deepcopy(cfg)
        c.mapping.iters, c.mapping.rays_without_depth = 2, rule
        keyframes = KeyframeStore([copy.deepcopy(kf) for kf in s.keyframes.frames])
        res = mapper.map_frame(copy.deepcopy(s.scene), 5, frame.color, depth, s.state.est[-1], s.intr, keyframes, c,
                               torch.Generator().manual_seed(3))
        assert res.ok and len(seen[rule]) == 2
    per_frame = cfg.mapping.pixels // len(res.window)
    # render: about half of the current frame's share of pixels has no depth and is mapped on its colour
    assert all(0.3 * per_frame < int((d <= 0).sum()) < 0.7 * per_frame for d in seen["render"])
    # skip: the same pixels drawn (the first iteration, before the draws differ), those without depth left out
    first = seen["render"][0]
    assert torch.equal(seen["skip"][0], first[first > 0])
    assert all(bool((d > 0).all()) for d in seen["skip"])
