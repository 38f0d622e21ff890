import pytest
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


@pytest.mark.parametrize("storage", ["float32", "compact"])
def test_spilled_keyframes_read_back_bit_identical(tmp_path, storage):
    import torch

    from slam.engine.keyframes import Keyframe, KeyframeStore, bytes_per_keyframe

    g = torch.Generator().manual_seed(0)
    H, W = 7, 9  # odd pixel count: a float16 depth after 8-bit colour would be misaligned in one buffer
    images = [(torch.rand(H, W, 3, generator=g), torch.rand(H, W, generator=g) * 4.0) for _ in range(5)]
    ref, store = KeyframeStore(storage=storage), KeyframeStore(storage=storage, in_memory=2, spill_dir=str(tmp_path))
    for i, (c, d) in enumerate(images):
        for s in (ref, store):
            s.add(Keyframe(i, c.clone(), d.clone(), torch.tensor([1.0, 0, 0, 0, i, 0, 0])))
    per = bytes_per_keyframe(H, W, storage)
    assert [kf.color is None for kf in store.frames] == [True, True, True, False, False]
    assert store.nbytes == 2 * per and store.spilled_bytes == 3 * per and ref.nbytes == 5 * per
    for a, b in zip(ref.frames, store.frames):
        assert torch.equal(a.rgb(), b.rgb()) and torch.equal(a.metres(), b.metres())
        assert [t.dtype for t in a.images()] == [t.dtype for t in b.images()]


def test_a_dropped_spilled_keyframe_gives_its_slot_back():
    import torch

    from slam.engine.keyframes import Keyframe, KeyframeStore

    store = KeyframeStore(max_keyframes=4, in_memory=1)
    xs = [0.0, 0.5, 0.52, 1.0, 1.5, 2.0]  # keyframes 2, then 1 (ties go to the first) are dropped while spilled
    for i, x in enumerate(xs):
        store.add(Keyframe(i, torch.full((2, 2, 3), float(i)), torch.full((2, 2), float(i)),
                           torch.tensor([1.0, 0, 0, 0, x, 0, 0])))
    assert [kf.index for kf in store.frames] == [0, 3, 4, 5] and store.dropped == 2
    assert store.spill.in_use == 3 and store.spilled_bytes == 3 * 2 * 2 * 16
    assert [float(kf.metres()[0, 0]) for kf in store.frames] == [0.0, 3.0, 4.0, 5.0]


def test_a_spill_that_cannot_be_written_keeps_the_images_in_memory(monkeypatch, caplog):
    import errno

    import torch

    from slam.engine import keyframe_spill
    from slam.engine.keyframes import Keyframe, KeyframeStore

    def full(self, color, depth):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(keyframe_spill.SpillFile, "write", full)
    store = KeyframeStore(in_memory=1)
    for i in range(3):
        store.add(Keyframe(i, torch.full((2, 2, 3), float(i)), torch.ones(2, 2), torch.tensor([1.0, 0, 0, 0, 0, 0, 0])))
    assert all(kf.color is not None for kf in store.frames) and store.nbytes == 3 * 2 * 2 * 16
    assert "No space left on device" in store.spill_error and "keyframe_spill_dir" in caplog.text
    assert float(store.frames[0].rgb()[0, 0, 0]) == 0.0
