"""Shared configurations for the speed benchmarks: the paper's Replica room0 scene, 40k query points."""

import pytest
import torch
import torch.nn.functional as F

import tdfields

ROOM0 = [[-1.9, 7.9], [-2.2, 4.5], [-2.5, 2.3]]
POINTS = 40_000  # one tracking batch: 1,000 rays x 40 samples (Replica: 2,000 rays x 40 in the paper)


def room0_box():
    return tdfields.enlarge_bounds(ROOM0, 0.24).tolist()


# name -> spec; "eslam" = tri-planes, "lrslam" = CP geometry + Six-axis appearance (docs/tdfields.md, "The decompositions")
CONFIGS = {
    "geometry/eslam-triplane": {"kind": "triplane", "cell_size": [0.24, 0.06], "channels": 32},
    "geometry/lrslam-cp": {"kind": "cp", "cell_size": [0.24, 0.06], "channels": 32, "rank": 2},
    "appearance/eslam-triplane": {"kind": "triplane", "cell_size": [0.24, 0.03], "channels": 32},
    "appearance/lrslam-six_axis": {"kind": "six_axis", "cell_size": [0.24, 0.03], "channels": 32, "rank": 16},
    # the same field on its O(n)-memory factor path, to show what plane composition saves
    "appearance/lrslam-six_axis-factors": {"kind": "six_axis", "cell_size": [0.24, 0.03], "channels": 32, "rank": 16,
                                           "strategy": "factors"},
}
# ESLAM's own tri-plane query (F.grid_sample on [1, C, H, W] planes): the reference the speed targets compare with
GRID_SAMPLE = {"geometry/eslam-grid_sample": "geometry/eslam-triplane",
               "appearance/eslam-grid_sample": "appearance/eslam-triplane"}


class GridSampleTriPlane(torch.nn.Module):
    """ESLAM's tri-plane lookup, as its code does it: normalise to [-1, 1] with the enlarged bound, bilinear
    ``grid_sample`` (align_corners=True, border padding) on each ``[1, C, n_b, n_a]`` plane, sum the three planes
    of a level, concatenate the levels. Holds the same values as the tdfields TriPlane it is built from."""

    def __init__(self, field: tdfields.MultiResolution):
        super().__init__()
        self.register_buffer("aabb", field.levels[0].aabb.clone())
        self.planes = torch.nn.ParameterList()
        for level in field.levels:
            for name in ("xy", "xz", "yz"):
                # tdfields stores [n_a, n_b, C]; grid_sample wants [1, C, n_b, n_a] (last dim is x of the grid)
                self.planes.append(torch.nn.Parameter(level.factors[name].detach().permute(2, 1, 0)[None].contiguous()))
        self.n_levels = len(field.levels)

    def forward(self, points):
        box = self.aabb
        p = 2 * (points - box[:, 0]) / (box[:, 1] - box[:, 0]) - 1
        out = []
        for level in range(self.n_levels):
            acc = 0
            for j, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
                grid = p[:, [a, b]][None, :, None]
                s = F.grid_sample(self.planes[3 * level + j], grid, mode="bilinear", padding_mode="border",
                                  align_corners=True)
                acc = acc + s[0, :, :, 0].T
            out.append(acc)
        return torch.cat(out, -1)


def build(name, device="cpu"):
    torch.manual_seed(0)
    if name in GRID_SAMPLE:
        return GridSampleTriPlane(build(GRID_SAMPLE[name], device)).to(device)
    return tdfields.build({**CONFIGS[name], "aabb": room0_box()}).to(device)


def points(device="cpu"):
    box = torch.tensor(room0_box())
    g = torch.Generator().manual_seed(0)
    return (box[:, 0] + torch.rand(POINTS, 3, generator=g) * (box[:, 1] - box[:, 0])).to(device)


@pytest.fixture(scope="module")
def query_points():
    return points()
