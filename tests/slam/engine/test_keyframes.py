import torch

from slam.engine.keyframes import overlapping_keyframes, select_window


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


def test_compact_storage_bounds_the_error_and_the_bytes():
    import torch

    from slam.engine.keyframes import Keyframe, KeyframeStore, bytes_per_keyframe

    g = torch.Generator().manual_seed(0)
    color = torch.rand(12, 16, 3, generator=g)
    depth = torch.rand(12, 16, generator=g) * 4.0
    full, compact = KeyframeStore(), KeyframeStore(storage="compact")
    for store in (full, compact):
        store.add(Keyframe(0, color.clone(), depth.clone(), torch.tensor([1.0, 0, 0, 0, 0, 0, 0])))
    assert full.nbytes == bytes_per_keyframe(12, 16) == 12 * 16 * 16
    assert compact.nbytes == bytes_per_keyframe(12, 16, "compact") == 12 * 16 * 5
    kf = compact.frames[0]
    assert kf.rgb().dtype == torch.float32 and float((kf.rgb() - color).abs().max()) <= 0.5 / 255 + 1e-7
    assert float(((kf.metres() - depth).abs() / depth).max()) <= 2.0**-11


def test_max_keyframes_drops_the_most_redundant_pose():
    import torch

    from slam.engine.keyframes import Keyframe, KeyframeStore

    store = KeyframeStore(max_keyframes=4)
    xs = [0.0, 0.5, 0.52, 1.0, 1.5]  # keyframe 2 sits 2 cm from keyframe 1: the redundant one
    for i, x in enumerate(xs):
        store.add(Keyframe(i, torch.zeros(2, 2, 3), torch.ones(2, 2), torch.tensor([1.0, 0, 0, 0, x, 0, 0])))
    assert [kf.index for kf in store.frames] == [0, 1, 3, 4] and store.dropped == 1
