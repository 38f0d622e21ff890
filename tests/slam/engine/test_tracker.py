"""Tracking reads the map as mapping left it, in the SLAM loop's own order and with its own (fused) optimizer; a
frame without depth is tracked on its colour (``track_on_color``) against an analytic room whose true pose is known
exactly."""

import math

import pytest
import torch

from slam.config import load_config
from slam.core.pose import matrix_to_pose, pose_to_matrix, rotation_angle
from slam.data.types import Intrinsics
from slam.model.scene import SceneModel
from slam.engine.tracker import track_frame, track_on_color
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
                                    f"representation={rep}", f"parallel={parallel}"], profile="quality")
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


HALF, T = 2.0, 0.06  # the room is the cube [-2, 2]^3 m; TSDF truncation in metres


def texture(p):
    """``[P, 3]`` -> ``[P, 3]`` RGB: smooth stripes across the walls (gradients in both image directions)."""
    x, y = p[:, 0], p[:, 1]
    return torch.stack((0.5 + 0.3 * torch.sin(3 * x + 1) * torch.cos(2 * y), 0.5 + 0.3 * torch.cos(4 * y - x),
                        0.5 + 0.2 * torch.sin(2 * x + 3 * y)), -1)


class Room(torch.nn.Module):
    """The SDF scene interface (``sdf``, ``rgb``, ``beta``, ``aabb``) with an exact SDF: free space positive, in
    truncation units, clamped to [-1, 1] as the learned one is."""

    def __init__(self):
        super().__init__()
        self.register_buffer("aabb", torch.tensor([[-HALF, HALF]] * 3))
        self.beta = torch.tensor(10.0)

    def sdf(self, p):
        return ((HALF - p.abs().amax(-1)) / T).clamp(-1, 1)

    def rgb(self, p):
        return texture(p)


def room_image(h=48, w=64, f=50.0):
    intr = Intrinsics(f, f, (w - 1) / 2, (h - 1) / 2, h, w)
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    hit = torch.stack((HALF * (u - intr.cx) / f, HALF * (v - intr.cy) / f, torch.full_like(u, HALF)), -1)
    return texture(hit.reshape(-1, 3)).reshape(h, w, 3), intr  # camera at the origin looking down +z


def turned(deg_x, deg_y):
    a, b = math.radians(deg_x), math.radians(deg_y)
    rx = torch.tensor([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = torch.tensor([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    m = torch.eye(4)
    m[:3, :3] = rx @ ry
    return m


ROOM_CFG = ["tracking.pixels=300", "tracking.ignore_edge=[0,0]", "rendering.n_stratified=32", "rendering.n_importance=8",
            "tracking.lr_r=0.002", "tracking.iters=40"]


def test_colour_tracking_turns_the_camera_back_to_the_wall_it_sees():
    color, intr = room_image()
    cfg = load_config("synthetic", ROOM_CFG, profile="quality")
    start = turned(1.5, -2.0)
    res, before = track_on_color(Room(), color, intr, matrix_to_pose(start), cfg, torch.Generator().manual_seed(0))
    assert res.ok and res.inliers == 1.0  # every ray ends on the wall
    err = math.degrees(float(rotation_angle(pose_to_matrix(res.pose)[:3, :3])))
    assert res.loss < 0.1 * before, (res.loss, before)  # measured: 34x lower
    assert err < 0.5, err  # from 2.5 degrees off (measured: 0.15)
    assert torch.equal(res.pose[4:], matrix_to_pose(start)[4:])  # translation is the prediction's
