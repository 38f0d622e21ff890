import pytest
import torch

import tdfields

ROOM0 = [[-1.9, 7.9], [-2.2, 4.5], [-2.5, 2.3]]


def test_enlarge_bounds_room0():
    b = tdfields.enlarge_bounds(ROOM0, 0.24)
    assert b.dtype == torch.float32
    torch.testing.assert_close(b[:, 1], torch.tensor([7.94, 4.52, 2.54]))
    torch.testing.assert_close(b[:, 1] - b[:, 0], torch.tensor([9.84, 6.72, 5.04]))


def test_grid_shape_uses_float32_floor():
    b = tdfields.enlarge_bounds(ROOM0, 0.24)
    assert tdfields.grid_shape_for(b, 0.24) == (41, 27, 21)  # 27, not 28: float32 6.7199995 / 0.24
    assert tdfields.grid_shape_for(b, 0.06) == (164, 111, 84)
    assert tdfields.grid_shape_for(b, 0.03) == (328, 223, 168)


@pytest.mark.parametrize("bad, match", [
    ([[0, 1], [0, 1]], "shape"),
    ([[0, 1], [0, float("nan")], [0, 1]], "NaN"),
    ([[0, 1], [1, 0], [0, 1]], "y interval"),
])
def test_bad_aabb(bad, match):
    with pytest.raises(ValueError, match=match):
        tdfields.enlarge_bounds(bad)


def test_contains():
    box = torch.tensor([[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    pts = torch.tensor([[0.5, 0.5, 0.5], [1.0, 1.0, 1.0], [1.01, 0.5, 0.5]])
    assert tdfields.contains(box, pts).tolist() == [True, True, False]
