"""System-level tests on a tiny generated synthetic sequence: robustness, determinism, the e2e CLI run."""

import json
import os

import pytest
import torch

from slam.config import load_config
from slam.errors import SlamInputError

from tests.slam.conftest import TINY


def _system(tiny_seq, extra=()):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, *extra], profile="quality")
    return SLAM(cfg, load_data(cfg))


class _Holes:
    """Dataset wrapper whose frame ``bad`` has no valid depth."""

    def __init__(self, ds, bad):
        self.ds, self.bad = ds, bad
        self.gt_poses, self.timestamps, self.gt_mesh_path = ds.gt_poses, ds.timestamps, ds.gt_mesh_path

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, i):
        f = self.ds[i]
        if i == self.bad:
            f.depth = torch.zeros_like(torch.as_tensor(f.depth))
        return f


def test_invalid_depth_frame_is_skipped(tiny_seq):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY], profile="quality")
    s = SLAM(cfg, _Holes(load_data(cfg), 4))
    s.run(progress=False)
    assert [e["frame"] for e in s.state.events] == [4]
    assert all(torch.isfinite(p).all() for p in s.state.est)
    assert all(torch.isfinite(p).all() for p in s.scene.parameters())
    assert len(s.state.est) == 6


def test_nan_tracking_falls_back_to_constant_velocity(tiny_seq, monkeypatch):
    import slam.engine.tracking as system
    from slam.core.pose import constant_velocity
    from slam.engine.tracker import TrackResult

    real = system.track_frame
    calls = {"n": 0}

    def flaky(scene, color, depth, intr, init, cfg, gen):
        calls["n"] += 1
        if calls["n"] == 3:  # frame 3
            return TrackResult(init.clone(), float("nan"), False, "non-finite tracking loss")
        return real(scene, color, depth, intr, init, cfg, gen)

    monkeypatch.setattr(system, "track_frame", flaky)
    s = _system(tiny_seq)
    s.run(progress=False)
    assert any(e["frame"] == 3 and "constant-velocity" in e["event"] for e in s.state.events)
    assert torch.allclose(s.state.est[3], constant_velocity(s.state.est[2], s.state.est[1]))


def test_tracker_returns_init_on_nan_loss(tiny_seq):
    from slam.engine.tracker import track_frame

    s = _system(tiny_seq)
    with torch.no_grad():
        for p in s.scene.fields.parameters():
            p.fill_(float("nan"))
    f = s.ds[1]
    init = torch.tensor([1.0, 0, 0, 0, 0, 0, 0])
    res = track_frame(s.scene, torch.as_tensor(f.color), torch.as_tensor(f.depth), s.intr, init, s.cfg, s.gen)
    assert not res.ok and torch.equal(res.pose, init)


@pytest.mark.parametrize("parallel", ["false", "true"])
def test_deterministic_for_a_seed_wherever_the_keyframes_live_and_whichever_adam(tiny_seq, parallel, monkeypatch):
    # b keeps one keyframe's images in memory and spills the rest: every mapping window reads spilled keyframes
    # back, on the mapping thread in parallel mode; c maps with torch.optim.Adam(fused=True), the reference of the
    # mapper's FusedAdam, here with carried moments and BA (two optimisers a call). Trajectory and map bit-identical.
    import functools

    import slam.engine.mapper as mapper
    from slam.core.optim import FusedAdam, adam

    sched = ["data.max_frames=7", "mapping.every_frame=1", "mapping.keyframe_every=1", f"parallel={parallel}",
             "mapping.optimizer_state=persistent", "mapping.ba_min_keyframes=2"]
    made = []

    def spied(groups, **kw):
        made.append(adam(groups, **kw))
        return made[-1]

    monkeypatch.setattr(mapper, "adam", spied)
    a = _system(tiny_seq, [*sched, "mapping.keyframes_in_memory=0"])
    a.run(progress=False)
    b = _system(tiny_seq, [*sched, "mapping.keyframes_in_memory=1"])
    b.run(progress=False)
    assert made and all(isinstance(o, FusedAdam) for o in made) and any(o.state for o in made)
    assert sum(len(o.param_groups[0]["params"]) == 1 for o in made) >= 3  # BA's pose optimisers ran
    monkeypatch.setattr(mapper, "adam", functools.partial(adam, reference=True))
    c = _system(tiny_seq, [*sched, "mapping.keyframes_in_memory=0"])
    c.run(progress=False)
    assert a.keyframes.spilled_bytes == 0 and b.keyframes.spilled_bytes == (len(b.keyframes) - 1) * 60 * 80 * 16
    assert b.keyframes.nbytes == 60 * 80 * 16
    for other in (b, c):
        assert torch.equal(torch.stack(a.state.est), torch.stack(other.state.est))
        for name, t in a.scene.state_dict().items():
            assert torch.equal(other.scene.state_dict()[name], t), name


@pytest.mark.parametrize("representation,parallel", [("lrslam", "true"), ("eslam", "true"), ("lrslam", "false")])
def test_fused_kernels_follow_the_reference_path_through_a_run(tiny_seq, representation, parallel, monkeypatch):
    # the fused kernels' shortcuts (merged rank loops, points with zero gradient skipped) and the fused render tail
    # (rendering.fused) checked where they run: tracking and mapping in both loop modes with fused Adam, BA and the
    # frozen-field caches, against the pure-torch path (the backend "torch" turns the render tail off too)
    from slam.core import fused_render
    from tdfields import kernels

    calls = {"composite": 0, "loss_terms": 0}
    for name in calls:
        def counted(*args, _fn=getattr(fused_render, name), _name=name):
            calls[_name] += 1
            return _fn(*args)
        monkeypatch.setattr(fused_render, name, counted)
    runs = {}
    for backend in ("torch", "numba"):
        with kernels.use_backend(backend):
            # every frame mapped and a keyframe, BA from the second keyframe on: the TUM preset's schedule. ICP's
            # start is not under test, and the constant-velocity start keeps it out: each change to ICP moved this
            # run's trajectory, and some trajectories put a float threshold (the colour cutoff, the SDF terms'
            # bands) on a sample in one path and not the other, a first gradient for Adam and a full step of that
            # factor entry (appearance factors 0.02 apart while the poses agreed to 4e-6)
            s = _system(tiny_seq, [f"representation={representation}", f"parallel={parallel}", "data.max_frames=5",
                                   "mapping.every_frame=1", "mapping.keyframe_every=1", "mapping.ba_min_keyframes=1",
                                   "rendering.fused=true", "tracking.init=const_speed"])
            s.run(progress=False)
            runs[backend] = (torch.stack(s.state.est), s.scene.state_dict())
        # the tail runs in the numba run only, in tracking and mapping alike
        assert (min(calls.values()) > 0) == (backend == "numba"), (backend, calls)
    (ref_poses, ref_map), (poses, fused_map) = runs["torch"], runs["numba"]
    torch.testing.assert_close(poses, ref_poses, rtol=0, atol=1e-4)
    for name, t in ref_map.items():
        torch.testing.assert_close(fused_map[name], t, rtol=1e-3, atol=1e-4, msg=name)


# the fast preset's tracker (second-order, the matrix once a round) and carried map moments, in the other loop mode
FAST_LEVERS = ["tracking.optimizer=gauss_newton", "tracking.gn_hessian=first", "mapping.optimizer_state=persistent"]


@pytest.mark.parametrize("parallel,levers", [("true", []), ("false", FAST_LEVERS)])
def test_the_triton_render_tail_follows_the_reference_path_through_a_run(tiny_seq, parallel, levers, monkeypatch):
    # the tail CUDA runs with TDFIELDS_BACKEND=triton, in the loop's call order (tracking, mapping with fused Adam
    # and BA, both loop modes), against the pure-torch path. Here it runs in Triton's interpreter on CPU tensors,
    # between numba's field kernels; the interpreter patches triton.language module-wide for each launch, so a lock
    # keeps the two threads' launches from overlapping (compiled kernels need none), and 512 rays a block keep the
    # interpreter's per-block cost down (the block size is the unit tests' concern).
    import threading

    from slam.core import fused_render, render_kernels_triton
    from tdfields import kernels

    if os.environ.get("TRITON_INTERPRET", "") in ("", "0") or not kernels.triton_available():
        pytest.skip("the Triton tail runs on CPU tensors only in Triton's interpreter")
    lock, launches, real = threading.Lock(), [], fused_render._launch

    def launch(backend, name, *args):
        with lock:
            launches.append(backend)
            real(backend, name, *args)

    # the constant-velocity start: ICP is not under test (the test above)
    overrides = ["representation=lrslam", f"parallel={parallel}", "data.max_frames=4", "mapping.every_frame=1",
                 "mapping.keyframe_every=1", "mapping.ba_min_keyframes=1", "rendering.fused=true",
                 "tracking.init=const_speed", *levers]
    with kernels.use_backend("torch"):
        ref = _system(tiny_seq, overrides)
        ref.run(progress=False)
    monkeypatch.setattr(fused_render, "_launch", launch)
    monkeypatch.setattr(fused_render, "_backend", lambda *t: "triton" if kernels.use_fused(*t) else None)
    monkeypatch.setattr(render_kernels_triton, "BLOCK", 512)
    with kernels.use_backend("numba"):
        s = _system(tiny_seq, overrides)
        s.run(progress=False)
    assert len(launches) > 50 and set(launches) == {"triton"}
    torch.testing.assert_close(torch.stack(s.state.est), torch.stack(ref.state.est), rtol=0, atol=1e-4)
    for name, t in ref.scene.state_dict().items():
        torch.testing.assert_close(s.scene.state_dict()[name], t, rtol=1e-3, atol=1e-4, msg=name)


def test_cuda_request_without_gpu_is_a_user_error():
    from slam.engine.setup import resolve_device

    if torch.cuda.is_available():
        pytest.skip("a GPU exists")
    with pytest.raises(SlamInputError, match="CUDA"):
        resolve_device("cuda")


def test_cli_errors_exit_2(tiny_seq, tmp_path, capsys):
    from slam.cli import main

    assert main(["run", "--config", "no/such", "--out", str(tmp_path)]) == 2
    assert main(["run", "--out", str(tmp_path), "tracking.nope=1"]) == 2
    assert main(["run", "--config", "tum/fr1_rpy-cpu", "--data", str(tiny_seq), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "expects tum data" in err
    if not torch.cuda.is_available():
        assert main(["run", "--data", str(tiny_seq), "--device", "cuda", "--out", str(tmp_path)]) == 2


def test_params_command_table1(tmp_path, capsys):
    from slam.cli import main

    out = tmp_path / "p.json"
    assert main(["params", "--config", "replica/room0", "--json", str(out)]) == 0
    assert json.loads(out.read_text()) == {"geometry": 28672, "appearance": 827392, "decoders": 2693,
                                           "total": 858757}
    assert main(["params", "--config", "replica/room0", "representation=eslam", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["total"] == 6789445
    assert main(["params", "--config", "scannet/scene0000", "representation=eslam", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["total"] == 17633349


@pytest.mark.slow
def test_end_to_end_run(tiny_seq, tmp_path):
    from slam.cli import main

    out = tmp_path / "run"
    rc = main(["run", "--config", "synthetic", "--profile", "quality", "--data", str(tiny_seq), "--out", str(out), "--quiet", "data.max_frames=16",
               "tracking.pixels=200", "mapping.iters_first=60", "mapping.pixels=400", "meshing.resolution=0.04"])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["num_frames"] == 16
    assert m["ate_rmse_m"] < 0.03
    for key in ("ate_mean_m", "fpt_s", "parameters", "reconstruction"):
        assert key in m
    assert set(m["parameters"]) == {"geometry", "appearance", "decoders", "total"}
    import trimesh

    mesh = trimesh.load(out / "mesh.ply", process=False)
    assert len(mesh.faces) > 100
    for name in ("trajectory.txt", "trajectory_gt.txt", "trajectory.png", "config.yaml", "checkpoint.pt", "frames.csv"):
        assert (out / name).is_file(), name
    import csv

    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert [int(r["k"]) for r in rows] == list(range(16)) and all(r["trusted"] == "1" for r in rows)
    assert rows[0]["tracking_iters"] == "" and all(int(r["tracking_iters"]) >= 1 for r in rows[1:])
    assert m["tracking_iters_mean"] == sum(int(r["tracking_iters"]) for r in rows[1:]) / 15
    from slam.eval import frame_steps, read_tum_trajectory

    truth = frame_steps(read_tum_trajectory(out / "trajectory_gt.txt")[1])  # the steps the camera took
    for key in ("turn_deg", "move_cm"):
        assert m["frame_steps"][key]["median"] == pytest.approx(truth[key]["median"], abs=0.3)
    # re-extract from the checkpoint
    assert main(["mesh", str(out / "checkpoint.pt"), "--resolution", "0.08", "--out", str(tmp_path / "m.ply")]) == 0
    assert (tmp_path / "m.ply").stat().st_size > 0
