"""Frames read ahead on a background thread are the frames read on demand, in any order of requests."""

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


def test_a_frame_of_another_size_is_a_bad_frame_not_an_exception(tiny_seq):
    ds = load_dataset(tiny_seq)
    f = read_frame(ds, 0, 0, (10, 10), torch.device("cpu"))
    assert not f.ok and "expected (10, 10)" in f.error and f.color is None
