import torch

from slam.keyframes import overlapping_keyframes, select_window


def test_select_window_always_has_last_two_and_caps_random():
    overlap = torch.ones(30, dtype=torch.bool)
    w = select_window(30, overlap, window_size=5, generator=torch.Generator().manual_seed(0))
    assert 28 in w and 29 in w
    assert len(w) == 4 + 2
    assert w == sorted(w)


def test_select_window_uses_only_overlapping():
    overlap = torch.zeros(10, dtype=torch.bool)
    overlap[[1, 4]] = True
    overlap[9] = False  # the last two are always in
    assert select_window(10, overlap, window_size=20) == [1, 4, 8, 9]
    assert select_window(2, torch.zeros(2, dtype=torch.bool)) == [0, 1]
    assert select_window(0, torch.zeros(0, dtype=torch.bool)) == []


def test_overlap_projection():
    H, W = 60, 80
    depth = torch.full((H, W), 2.0)
    same = torch.eye(4)
    behind = torch.eye(4)
    behind[:3, :3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0]))  # looks backwards
    far = torch.eye(4)
    far[0, 3] = 100.0
    kf = torch.stack((same, behind, far))
    mask = overlapping_keyframes(depth, torch.eye(4), kf, 50.0, 50.0, 40.0, 30.0, H, W,
                                 generator=torch.Generator().manual_seed(0))
    assert mask.tolist() == [True, False, False]
