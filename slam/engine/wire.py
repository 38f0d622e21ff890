"""Tensors across the pipe to the mapper process (:mod:`slam.engine.map_process`): as numpy arrays, which pickle
as their raw bytes, instead of torch tensors, which pickle through ``torch.save``."""

from __future__ import annotations

import torch

__all__ = ["pack_state", "unpack_state"]


def pack_state(tensors: dict) -> dict:
    """``{name: tensor}`` -> ``{name: numpy array}``, CPU copies: a numpy array pickles as its raw bytes, a torch
    tensor through ``torch.save`` (a map's snapshot took 3.5 ms to pickle and 3.2 to unpickle as tensors, 1 and
    0.1-0.6 as arrays). A dtype numpy lacks stays a tensor."""
    out = {}
    for name, t in tensors.items():
        t = t.detach().cpu()
        try:
            out[name] = t.numpy().copy()
        except TypeError:
            out[name] = t.clone()
    return out


def unpack_state(arrays: dict) -> dict:
    """The inverse of :func:`pack_state`: ``{name: tensor}`` (sharing the arrays' memory)."""
    return {name: torch.from_numpy(a) if not isinstance(a, torch.Tensor) else a for name, a in arrays.items()}
