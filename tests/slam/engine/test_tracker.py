"""Tracking reads the map as mapping left it, in the SLAM loop's own order and with its own (fused) optimizer."""

import pytest
import torch

from slam.config import load_config
from slam.model.scene import SceneModel
from slam.engine.tracker import track_frame
from tests.slam.conftest import TINY


def _fresh_copy(system):
    """A scene that never queried anything: the same parameters loaded into a new model."""
    model = SceneModel(system.cfg, system.aabb)
    model.load_state_dict(system.scene.state_dict())
    return model


@pytest.mark.parametrize("rep,parallel", [("lrslam", "false"), ("sa_sa", "false"), ("eslam", "false"),
                                          ("lrslam", "true")])
def test_tracking_after_mapping_sees_the_map_mapping_wrote(tiny_seq, rep, parallel):
    from slam.engine.setup import load_data
    from slam.engine.system import SLAM

    cfg = load_config("synthetic", [f"data.path={tiny_seq}", *TINY, "mapping.every_frame=1",
                                    f"representation={rep}", f"parallel={parallel}"])
    system = SLAM(cfg, load_data(cfg))
    for k in range(4):  # map, then (track, map) three times: every tracking call follows a mapping call
        system.step(k)
    system.finish()  # parallel: the tracker's copy now holds the mapper's last map
    frame = system.ds[system.indices[4]]
    color = torch.as_tensor(frame.color, dtype=torch.float32)
    depth = torch.as_tensor(frame.depth, dtype=torch.float32)
    init = system.state.est[-1]
    results = []
    for scene in (system.mapper.track_scene, _fresh_copy(system)):
        gen = torch.Generator().manual_seed(7)
        results.append(track_frame(scene, color, depth, system.intr, init, cfg, gen))
    assert results[0].ok and results[1].ok
    torch.testing.assert_close(results[0].pose, results[1].pose, rtol=0, atol=1e-6)
    assert results[0].loss == pytest.approx(results[1].loss, rel=1e-6)
    system.close()
