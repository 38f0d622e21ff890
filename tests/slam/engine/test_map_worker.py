"""Parallel mapping: the tracker reads exactly the map a finished mapping call left (never one mid-step), the one
the schedule names, and a parallel run repeats exactly; sequential mode is the same schedule with lag 1."""

import hashlib

import pytest
import torch

import slam.engine.map_worker as mw
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
                                    f"mapping.every_frame={every}", f"parallel={str(parallel).lower()}"])
    seen, written = {}, {}
    real_track, real_map = tracking_mod.track_frame, mw.map_frame

    def track(scene, *a, **k):
        seen[len(s.state.est)] = _digest(scene)  # frame position being tracked
        return real_track(scene, *a, **k)

    def mapping(scene, index, *a, **k):
        res = real_map(scene, index, *a, **k)
        written[index] = _digest(scene)  # the map as this call leaves it
        return res

    monkeypatch.setattr(tracking_mod, "track_frame", track)
    monkeypatch.setattr(mw, "map_frame", mapping)
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
                                    "parallel=true", "meshing.resolution=0.1"])
    faces = []

    class Mesher(Observer):
        def on_frame(self, run, rec):
            faces.append(len(run_mesh(run, cull=False).faces))

    s = SLAM(cfg, load_data(cfg))
    s.run(progress=False, observers=[Mesher()])
    s.close()
    assert len(faces) == 8 and not [e for e in s.state.events if "mapping" in e["event"]]
