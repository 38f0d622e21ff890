"""The evaluation chain on the synthetic room: GT-pose culling keeps every observed surface."""

import numpy as np
import pytest
import torch
import trimesh

from slam.data import ReplicaDataset
from slam.data.synthetic import EVAL_CAMERA_BOX, SynthConfig, generate
from slam.eval import cull_mesh, depth_l1, reconstruction_metrics


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    return ReplicaDataset(generate(tmp_path_factory.mktemp("synth_eval") / "s", SynthConfig(frames=8, height=48, width=64)))


def test_culled_gt_keeps_observed_surface(seq):
    full = trimesh.load(seq.gt_mesh_path, process=False)
    culled = cull_mesh(full, seq.gt_poses, seq.intrinsics, depths=(f.depth for f in seq))
    assert 0.1 * full.area < culled.area < 0.8 * full.area
    # every back-projected depth pixel lies on the culled mesh
    f = seq[4]
    k = f.intrinsics
    v, u = torch.meshgrid(torch.arange(k.height), torch.arange(k.width), indexing="ij")
    z = f.depth
    cam = torch.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], -1).reshape(-1, 3).double()
    pts = (cam @ f.pose[:3, :3].double().T + f.pose[:3, 3].double()).numpy()[::5]
    _, dist, _ = trimesh.proximity.closest_point(culled, pts)
    assert np.percentile(dist, 99) < 5e-3
    # the culled GT against a 1 cm shifted copy of itself
    shifted = culled.copy()
    shifted.apply_translation([0.0, 0.0, 0.01])
    floor = reconstruction_metrics(culled.copy(), culled, samples=50_000)["accuracy_m"]
    m = reconstruction_metrics(shifted, culled, samples=50_000)
    # floors and ceiling move 1 cm along their normal, walls within their plane: between floor and floor + 1 cm
    assert floor < m["accuracy_m"] < 0.01 + floor
    assert depth_l1(culled, culled, views=2, height=60, width=60, focal=36, camera_box=EVAL_CAMERA_BOX) == 0.0
