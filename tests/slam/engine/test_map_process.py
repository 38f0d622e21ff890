"""The mapper in its own process (``mapper_process: true``): the thread mode's run bit for bit, through a growth of
the box, a stop with a call pending and a resume; a child that dies is an error naming it, not a hang."""

import pytest
import torch

from slam.config import load_config
from slam.errors import SlamInputError
from tests.slam.conftest import GROWING, TINY

RUN = TINY[1:] + ["data.max_frames=10", *GROWING]  # synthetic maps frames 0, 4, 8, 9; the box grows once


def _traj(out) -> str:
    return (out / "trajectory.txt").read_text()


# with carried Adam moments (mapping.optimizer_state: persistent) the child holds them, sends them back when a
# checkpoint asks, starts a resumed run from the checkpoint's and resets them with a growth, as the thread does
@pytest.mark.parametrize("state", ["per_call", "persistent"])
def test_a_mapper_process_gives_the_thread_modes_run_through_a_growth_a_stop_and_a_resume(tiny_seq, tmp_path,
                                                                                           state):
    from slam.run.checkpoint import load_run
    from slam.run.runner import RunInterrupted, run_to_folder

    run = [f"data.path={tiny_seq}", *RUN, "parallel=true", f"mapping.optimizer_state={state}"]
    thread = load_config("synthetic", run, profile="quality")
    # and the process run reads its frames in the tracker's waits (data.prefetch_in: waits) in one of the two
    reader = "waits" if state == "persistent" else "thread"
    proc = load_config("synthetic", [*run, "mapper_process=true", f"data.prefetch_in={reader}"], profile="quality")
    full = run_to_folder(thread, tmp_path / "thread", progress=False, mesh=False)
    at = next(e["frame"] for e in full["events"] if "growth" in e)
    out = tmp_path / "process"
    with pytest.raises(RunInterrupted):
        run_to_folder(proc, out, progress=False, mesh=False, stop_after=at + 1)
    stopped = load_run(out / "checkpoint.pt")["extra"]
    assert stopped["aabb"][0][0] < -1.6, "stopped before the growth"
    assert [p["k"] for p in stopped["run"]["pending"]] == [4], "no call pending at the stop"
    done = run_to_folder(proc, out, progress=False, mesh=False, resume=True)  # a new child, from the checkpoint
    assert _traj(out) == _traj(tmp_path / "thread")  # bit for bit
    assert done["mapping_calls"] >= 1 and done["mapping_s"] > 0  # this session's calls, timed in the child
    a = load_run(tmp_path / "thread" / "checkpoint.pt")
    b = load_run(out / "checkpoint.pt")
    for name, t in a["state_dict"].items():
        assert torch.equal(t, b["state_dict"][name]), name
    ka, kb = a["extra"]["run"]["keyframes"], b["extra"]["run"]["keyframes"]
    assert [k["k"] for k in ka] == [k["k"] for k in kb]
    assert all(torch.equal(x["pose"], y["pose"]) for x, y in zip(ka, kb))  # BA's poses came back from the child
    assert torch.equal(a["extra"]["run"]["rng"]["map_gen"], b["extra"]["run"]["rng"]["map_gen"])
    ma, mb = a["extra"]["run"]["moments"], b["extra"]["run"]["moments"]
    assert (ma is None) == (mb is None) == (state == "per_call")
    if ma is not None:  # the calls after the growth (8, 9) carried theirs: the child's came back to the checkpoint
        assert {float(v["step"]) for v in ma.values()} == {6.0}
        for name in ma:
            assert all(torch.equal(ma[name][k], mb[name][k]) for k in ma[name]), name


def test_the_child_starts_from_the_moments_it_is_given_and_sends_back_the_inline_calls(tiny_seq):
    """A child started with carried Adam moments (a resumed run's) maps from them: the moments and the map its call
    sends back are those of the same call run inline from the same state, bit for bit."""
    import copy

    from slam.engine.map_process import MapProcess
    from slam.engine.wire import unpack_state
    from slam.engine.map_call import MapJob
    from slam.engine.mapper import MapMoments, map_frame
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=false", "mapping.every_frame=1",
                                    "mapping.keyframe_every=1", "mapping.optimizer_state=persistent"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    try:
        for k in range(3):
            s.step(k)
        state = s.mapper.moments.state
        assert {float(v["step"]) for v in state.values()} == {6.0}  # the calls of frames 1 and 2
        frame = s.frames.get(3)
        gen = torch.Generator()
        gen.set_state(s.map_gen.get_state())
        scene, keyframes, moments = copy.deepcopy(s.scene), copy.deepcopy(s.keyframes), MapMoments(state)
        # a call of 2 iterations instead of mapping.iters' 3 (a routine refresh's need_gap_iters): the job carries it
        inline = map_frame(scene, 3, frame.color, frame.depth, s.state.est[-1], s.intr, keyframes, cfg, gen,
                           moments=moments, iters=2)
        proc = MapProcess(cfg, s.intr, "cpu", lambda job, reply: reply)
        try:
            proc.start(s.scene, s.keyframes, s.map_gen, MapMoments(state))
            reply = proc.submit(MapJob(3, frame.color, frame.depth, s.state.est[-1], False, True, 2)).result()
            assert "moments" not in reply  # a call's reply: the map only, the moments on request
            carried = proc.moments()
        finally:
            proc.close()
        assert torch.equal(reply["result"].pose, inline.pose)
        for name, st in moments.state.items():
            assert float(st["step"]) == 8.0 and all(torch.equal(v, carried[name][k]) for k, v in st.items())
        snapshot = unpack_state(reply["snapshot"])
        for name, t in scene.state_dict().items():
            assert torch.equal(t, snapshot[name]), name
    finally:
        s.close()


def test_a_dead_mapper_process_is_an_error_that_names_it(tiny_seq):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.errors import SlamRunError

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=true", "mapper_process=true"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    try:
        assert s.mapper.process._proc.is_alive()  # spawned (and its imports done) before the first frame
        s.step(0)  # the warm-up: the child gets its replica
        s.mapper.wait_idle()
        s.mapper.process._proc.kill()
        with pytest.raises(SlamRunError, match=r"mapping process \(pid \d+\) ended unexpectedly \(SIGKILL"):
            for k in range(1, 6):
                s.step(k)
            s.finish()
    finally:
        s.close(abort=True)


def test_mapper_process_needs_parallel():
    with pytest.raises(SlamInputError, match="'mapper_process'"):
        load_config("synthetic", ["parallel=false", "mapper_process=true"], profile="quality")


def test_a_failed_call_is_not_paired_with_the_next_reply(tiny_seq):
    """A call that raised in the child leaves the process unusable: that call and every later one raise the same
    one-line error naming the mapping process (20b7b9c left the failed call first in its waiting list, so the next
    call's reply was taken as its own, and the next call waited for ever)."""
    import threading

    from slam.engine.map_process import MapProcess
    from slam.engine.map_call import MapJob
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.errors import SlamRunError

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=false", "preload_kernels=false"], profile="quality")
    s = SLAM(cfg, load_data(cfg))
    proc = MapProcess(cfg, s.intr, "cpu", lambda job, reply: reply)
    try:
        s.step(0)
        frame = s.frames.get(1)
        proc.start(s.scene, s.keyframes, s.map_gen)
        bad = proc.submit(MapJob(1, frame.color[:5], frame.depth, s.state.est[-1], False, True))  # a wrong shape
        good = proc.submit(MapJob(1, frame.color, frame.depth, s.state.est[-1], False, True))
        with pytest.raises(SlamRunError, match=r"the mapping process \(pid \d+\) failed: \w+") as info:
            bad.result()
        assert "Traceback" in info.value.detail and "\n" not in str(info.value)
        raised = []
        waiter = threading.Thread(target=lambda: raised.append(pytest.raises(SlamRunError, good.result)),
                                  daemon=True)
        waiter.start()
        waiter.join(timeout=60)
        assert raised and raised[0].value is info.value  # the same error, at once
        with pytest.raises(SlamRunError):
            proc.moments()
    finally:
        proc.close()
        s.close()
    assert proc._proc is None


def test_a_system_that_fails_to_start_ends_its_mapping_process_and_close_deletes_the_spill_file(tiny_seq, tmp_path,
                                                                                               monkeypatch):
    """A start that fails after the child was spawned ends the child; SLAM.close closes the keyframes' spill file,
    which can hold gigabytes (20b7b9c left both to the garbage collector)."""
    import slam.engine.system as system_mod
    from slam.engine.map_process import MapProcess
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "parallel=true", "mapper_process=true",
                                    "mapping.every_frame=1", "mapping.keyframe_every=1",
                                    "mapping.keyframes_in_memory=1", f"mapping.keyframe_spill_dir={tmp_path}"], profile="quality")
    spawned, real_spawn = [], MapProcess.spawn

    def spawn(self, *a, **k):
        spawned.append(self)
        real_spawn(self, *a, **k)

    def failing(*a, **k):
        raise MemoryError("made to fail by the test")

    monkeypatch.setattr(MapProcess, "spawn", spawn)
    monkeypatch.setattr(system_mod, "preload", failing)
    with pytest.raises(MemoryError):
        SLAM(cfg, load_data(cfg))
    assert spawned and spawned[0]._proc is None  # killed and joined
    monkeypatch.undo()
    s = SLAM(cfg, load_data(cfg))
    for k in range(4):
        s.step(k)
    s.mapper.wait_idle()
    handle = s.keyframes.spill._fh
    assert s.keyframes.spilled_bytes > 0 and not handle.closed
    s.close()
    assert handle.closed
    s.close()  # twice is fine


def test_the_public_switches_together_give_the_thread_modes_run_in_a_process_through_a_stop(tiny_seq, tmp_path):
    """The switches no preset turns on, where they meet the mapper process: a bounded keyframe store
    (``max_keyframes``: the child drops, the loop mirrors), keyframes spilled to disk, mapping by need with
    ``keyframe_every`` > 1, the Gauss-Newton tracker and carried moments; stopped and resumed. The process run is
    the thread run, byte for byte, with the same keyframes and poses."""
    from slam.run.checkpoint import load_run
    from slam.run.runner import RunInterrupted, run_to_folder

    run = [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=24", "parallel=true", "mapping.max_keyframes=4",
           "mapping.keyframes_in_memory=1", f"mapping.keyframe_spill_dir={tmp_path}", "mapping.schedule=by_need",
           "mapping.need_young=2", "mapping.need_max_gap=2", "mapping.keyframe_every=2",
           "mapping.optimizer_state=persistent", "tracking.optimizer=gauss_newton", "tracking.gn_iters=3"]
    full = run_to_folder(load_config("synthetic", run, profile="quality"), tmp_path / "thread", progress=False, mesh=False)
    proc = load_config("synthetic", [*run, "mapper_process=true"], profile="quality")
    out = tmp_path / "process"
    with pytest.raises(RunInterrupted):
        run_to_folder(proc, out, progress=False, mesh=False, stop_after=9)
    run_to_folder(proc, out, progress=False, mesh=False, resume=True)
    assert _traj(out) == _traj(tmp_path / "thread")
    a, b = (load_run(d / "checkpoint.pt")["extra"]["run"] for d in (tmp_path / "thread", out))
    assert [k["k"] for k in a["keyframes"]] == [k["k"] for k in b["keyframes"]]
    assert all(torch.equal(x["pose"], y["pose"]) for x, y in zip(a["keyframes"], b["keyframes"]))
    assert a["keyframes_dropped"] == b["keyframes_dropped"] > 0 and len(a["keyframes"]) == 4
    assert full["mapping_calls"] < 24  # by need: not every frame was mapped
