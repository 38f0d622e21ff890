"""Shared configurations for the speed benchmarks: the paper's Replica room0 scene, 40k query points."""

import pytest
import torch

import tdfields

ROOM0 = [[-1.9, 7.9], [-2.2, 4.5], [-2.5, 2.3]]
POINTS = 40_000  # one tracking batch: 1,000 rays x 40 samples (Replica: 2,000 rays x 40 in the paper)


def room0_box():
    return tdfields.enlarge_bounds(ROOM0, 0.24).tolist()


# name -> spec; "eslam" = tri-planes, "lrslam" = CP geometry + Six-axis appearance (method.md section 2)
CONFIGS = {
    "geometry/eslam-triplane": {"kind": "triplane", "cell_size": [0.24, 0.06], "channels": 32},
    "geometry/lrslam-cp": {"kind": "cp", "cell_size": [0.24, 0.06], "channels": 32, "rank": 2},
    "appearance/eslam-triplane": {"kind": "triplane", "cell_size": [0.24, 0.03], "channels": 32},
    "appearance/lrslam-six_axis": {"kind": "six_axis", "cell_size": [0.24, 0.03], "channels": 32, "rank": 16},
    # the same field on its O(n)-memory factor path, to show what plane composition saves
    "appearance/lrslam-six_axis-factors": {"kind": "six_axis", "cell_size": [0.24, 0.03], "channels": 32, "rank": 16,
                                           "strategy": "factors"},
}


def build(name, device="cpu"):
    torch.manual_seed(0)
    return tdfields.build({**CONFIGS[name], "aabb": room0_box()}).to(device)


def points(device="cpu"):
    box = torch.tensor(room0_box())
    g = torch.Generator().manual_seed(0)
    return (box[:, 0] + torch.rand(POINTS, 3, generator=g) * (box[:, 1] - box[:, 0])).to(device)


@pytest.fixture(scope="module")
def query_points():
    return points()
