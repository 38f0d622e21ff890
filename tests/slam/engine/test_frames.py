"""Frames read ahead, on a background thread or in the loop's waits, are the frames read on demand, in any order of
requests."""

import torch

from slam.data import load_dataset
from slam.engine.frames import FrameSource, read_frame


def test_prefetched_frames_equal_frames_read_on_demand(tiny_seq):
    ds = load_dataset(tiny_seq)
    shape = (ds.intrinsics.height, ds.intrinsics.width)
    idx = list(range(0, len(ds), 2))
    ahead = FrameSource(ds, idx, shape, torch.device("cpu"), ahead=3)
    for k in [0, 1, 2, 5, 3, 7, 8]:  # forwards, with a jump and a step back (resume reads keyframes out of order)
        a = ahead.get(k)
        b = read_frame(ds, k, idx[k], shape, torch.device("cpu"))
        assert a.ok and a.index == idx[k] and torch.equal(a.color, b.color) and torch.equal(a.depth, b.depth)
    ahead.close()
    assert FrameSource(ds, idx, shape, torch.device("cpu"), ahead=0).get(4).index == idx[4]


def test_frames_read_in_the_waits_are_read_in_order_only_while_the_wait_lasts(tiny_seq, monkeypatch):
    import slam.engine.frames as frames

    ds = load_dataset(tiny_seq)
    shape = (ds.intrinsics.height, ds.intrinsics.width)
    idx = list(range(len(ds)))
    reads = []
    monkeypatch.setattr(frames, "read_frame", lambda d, k, i, s, dev: reads.append(k) or read_frame(d, k, i, s, dev))
    src = FrameSource(ds, idx, shape, torch.device("cpu"), ahead=3, in_waits=True)
    assert src._pool is None  # no thread beside the loop
    polls = iter([True, True, False])  # the wait ends after two frames
    assert src.read_while(2, lambda: next(polls)) == 2 and reads == [2, 3]
    assert src.read_while(2, lambda: True) == 2 and reads == [2, 3, 4, 5]  # up to k + ahead, each frame once
    for k in (2, 3, 4, 6):  # taken from what was read, the rest on demand
        f = src.get(k)
        ref = read_frame(ds, k, idx[k], shape, torch.device("cpu"))
        assert f.index == idx[k] and torch.equal(f.color, ref.color) and torch.equal(f.depth, ref.depth)
    assert reads[4:] == [6] and not src._read  # frame 5 was skipped over: dropped, not kept
    assert FrameSource(ds, idx, shape, torch.device("cpu"), ahead=3).read_while(0, lambda: True) == 0
    src.close()


def test_a_frame_of_another_size_is_a_bad_frame_not_an_exception(tiny_seq):
    ds = load_dataset(tiny_seq)
    f = read_frame(ds, 0, 0, (10, 10), torch.device("cpu"))
    assert not f.ok and "expected (10, 10)" in f.error and f.color is None
