"""Tensors across the pipe to the mapper process: exact round trips, a dtype numpy lacks kept as a tensor."""

import pickle

import torch

from slam.engine.wire import pack_state, unpack_state


def test_a_state_crosses_a_pickle_bit_for_bit_and_apart_from_the_original():
    state = {"w": torch.randn(5, 3), "step": torch.tensor(7.0), "n": torch.arange(4), "h": torch.randn(2).bfloat16()}
    packed, before = pack_state(state), state["w"].clone()
    state["w"].add_(1.0)  # a copy was packed: the map goes on changing in the child
    back = unpack_state(pickle.loads(pickle.dumps(packed, protocol=pickle.HIGHEST_PROTOCOL)))
    assert isinstance(packed["w"], __import__("numpy").ndarray) and isinstance(packed["h"], torch.Tensor)
    assert torch.equal(back["w"], before) and back["step"].shape == ()
    assert torch.equal(back["n"], torch.arange(4)) and back["n"].dtype == torch.int64
    assert torch.equal(back["h"], state["h"]) and back["h"].dtype == torch.bfloat16
