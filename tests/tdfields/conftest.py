import pytest
import torch

import tdfields

BOX = [[-0.5, 0.7], [0.1, 1.0], [-0.3, 0.4]]
SHAPE = (5, 4, 6)

# kind -> constructor kwargs for a small field
SMALL = {
    "dense_grid": {},
    "triplane": {},
    "vector_matrix": {"rank": 3},
    "cp": {"rank": 3},
    "six_axis": {"rank": 3},
}


@pytest.fixture(params=sorted(SMALL))
def kind(request):
    return request.param


def make(kind, channels=4, shape=SHAPE, box=BOX, **kw):
    torch.manual_seed(0)
    return tdfields.build({"kind": kind, "aabb": box, "grid_shape": list(shape), "channels": channels,
                           **SMALL[kind], **kw})
