"""Parallel mapping: the tracker reads exactly the map a finished mapping call left (never one mid-step), the one
the schedule names, and a parallel run repeats exactly; sequential mode is the same schedule with lag 1."""

import hashlib

import pytest
import torch

import slam.engine.mapper as mapper_mod
import slam.engine.tracking as tracking_mod
from slam.config import load_config
from tests.slam.conftest import TINY


def _digest(module) -> str:
    h = hashlib.sha1()
    for name, t in module.state_dict().items():
        h.update(name.encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _run(tiny_seq, monkeypatch, parallel: bool, every: int):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=10",
                                    f"mapping.every_frame={every}", f"parallel={str(parallel).lower()}"], profile="quality")
    seen, written = {}, {}
    real_track, real_map = tracking_mod.track_frame, mapper_mod.map_frame

    def track(scene, *a, **k):
        seen[len(s.state.est)] = _digest(scene)  # frame position being tracked
        return real_track(scene, *a, **k)

    def mapping(scene, index, *a, **k):
        res = real_map(scene, index, *a, **k)
        written[index] = _digest(scene)  # the map as this call leaves it
        return res

    monkeypatch.setattr(tracking_mod, "track_frame", track)
    monkeypatch.setattr(mapper_mod, "map_frame", mapping)
    s = SLAM(cfg, load_data(cfg))
    s.run(progress=False)
    s.close()
    return s, seen, written


@pytest.mark.parametrize("parallel,every", [(True, 2), (True, 1), (False, 2)])
def test_the_tracker_reads_the_map_the_schedule_names(tiny_seq, monkeypatch, parallel, every):
    s, seen, written = _run(tiny_seq, monkeypatch, parallel, every)
    lag = max(every, 2) if parallel else 1
    assert s.mapper.lag == lag
    mapped = sorted(written)
    for j, digest in seen.items():
        m = max([k for k in mapped if k <= j - lag] or [mapped[0]])  # the warm-up at least
        assert digest == written[m], f"frame {j} tracked against another map than mapping call {m} left"
    assert _digest(s.scene) == written[mapped[-1]] == _digest(s.mapper.track_scene)


def test_a_parallel_run_repeats_exactly(tiny_seq, monkeypatch):
    a, _, _ = _run(tiny_seq, monkeypatch, True, 2)
    b, _, _ = _run(tiny_seq, monkeypatch, True, 2)
    assert torch.equal(torch.stack(a.state.est), torch.stack(b.state.est))
    assert _digest(a.scene) == _digest(b.scene)


def test_a_mesh_mid_run_waits_for_the_mapper_instead_of_freezing_its_scene(tiny_seq):
    """An observer meshing every frame (the viewer's previews) while the mapper thread optimises: the mesh comes
    from the tracker's copy, after the running call, and no mapping step loses its gradients."""
    from slam.engine.observers import Observer
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM
    from slam.model.mesher import run_mesh

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY[1:], "data.max_frames=8", "mapping.every_frame=1",
                                    "parallel=true", "meshing.resolution=0.1"], profile="quality")
    faces = []

    class Mesher(Observer):
        def on_frame(self, run, rec):
            faces.append(len(run_mesh(run, cull=False).faces))

    s = SLAM(cfg, load_data(cfg))
    s.run(progress=False, observers=[Mesher()])
    s.close()
    assert len(faces) == 8 and not [e for e in s.state.events if "mapping" in e["event"]]


def test_the_keyframe_mirror_takes_the_mapping_processs_drop_and_its_poses():
    """With ``mapping.max_keyframes`` the mapper process drops the keyframe that is most redundant by its BA-refined
    poses; the loop's mirror must drop the same frame and pair each pose with its own frame, though by the poses
    it held before the reply it would have dropped another (20b7b9c kept frame 1 with frame 2's pose)."""
    from slam.engine.keyframes import Keyframe, KeyframeStore
    from slam.engine.map_call import MapJob
    from slam.engine.map_worker import MapWorker
    from slam.engine.mapper import MapResult
    from slam.engine.wire import pack_state
    from slam.model.scene import SceneModel

    def pose(x):
        return torch.tensor([1.0, 0, 0, 0, x, 0, 0])

    cfg = load_config("synthetic", [*TINY[1:], "mapping.max_keyframes=4"], profile="quality")
    scene = SceneModel(cfg, torch.tensor([[-1.0, 1.0]] * 3))
    store = KeyframeStore.for_mapping(cfg.mapping)
    for i, x in enumerate([0.0, 0.5, 0.52, 1.0]):  # by these poses keyframe 2 (2 cm from 1) is the redundant one
        store.add(Keyframe(i, torch.full((2, 2, 3), float(i)), torch.full((2, 2), float(i)), pose(x)))
    worker = MapWorker(scene, store, cfg, None, torch.Generator(), parallel=False)
    # the child's BA moved keyframe 1 next to keyframe 0, so it dropped keyframe 1
    child = [pose(x) for x in (0.0, 0.52, 1.0, 1.5)]
    reply = {"result": MapResult(pose(1.5), [0, 1, 2, 3], 0.1, True, 0), "seconds": 0.01,
             "snapshot": pack_state(scene.state_dict()), "gen": torch.Generator().get_state(),
             "poses": torch.stack(child), "indices": [0, 2, 3, 4]}
    job = MapJob(4, torch.full((2, 2, 3), 4.0), torch.full((2, 2), 4.0), pose(1.5), first=False, keyframe=True)
    worker._arrived(job, reply)
    assert [kf.index for kf in store.frames] == [0, 2, 3, 4] and store.dropped == 1
    assert all(torch.equal(kf.pose, p) for kf, p in zip(store.frames, child))
    assert [float(kf.metres()[0, 0]) for kf in store.frames] == [0.0, 2.0, 3.0, 4.0]  # each frame its own images
    with pytest.raises(RuntimeError, match="keyframe mirror"):  # a reply naming frames the mirror lacks
        worker._arrived(MapJob(5, None, None, pose(2.0), False, False), {**reply, "indices": [0, 2, 3, 9]})
