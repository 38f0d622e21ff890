"""The random streams of a run as plain tensors and numbers, and back: torch's and numpy's global state and the
tracker's and the mapper's generators (a resumed run draws what the uninterrupted one would have)."""

from __future__ import annotations

import numpy as np
import torch


def _numpy_state() -> dict:
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos), "has_gauss": int(has_gauss),
            "cached": float(cached)}


def rng_state(gen: torch.Generator, map_gen: torch.Generator) -> dict:
    """``{"torch", "numpy", "gen", "map_gen"}``: every random state a run draws from."""
    return {"torch": torch.get_rng_state(), "numpy": _numpy_state(), "gen": gen.get_state(),
            "map_gen": map_gen.get_state()}


def set_rng_state(s: dict, gen: torch.Generator, map_gen: torch.Generator) -> None:
    """The inverse of :func:`rng_state`."""
    torch.set_rng_state(s["torch"])
    n = s["numpy"]
    np.random.set_state(("MT19937", n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"]))
    gen.set_state(s["gen"])
    map_gen.set_state(s["map_gen"])
