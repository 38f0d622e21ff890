"""The Adam both loops use: PyTorch's fused implementation where the device has one.

Fused Adam updates all parameters in one kernel instead of a dozen tensor ops per parameter: measured here
(1 thread) 3.3 ms vs 13.0 ms per step for ESLAM's 6.79M room0 parameters and 0.36 ms vs 1.26 ms for LRSLAM's
0.86M. It follows the same update rule as the default implementation.
"""

from __future__ import annotations

import torch

_FUSED_DEVICES = ("cpu", "cuda")


def adam(groups: list[dict], **kwargs) -> torch.optim.Adam:
    """``torch.optim.Adam(groups, **kwargs)``, fused when every parameter is a float tensor on the CPU or CUDA."""
    params = [p for g in groups for p in g["params"]]
    fused = bool(params) and all(p.device.type in _FUSED_DEVICES and p.is_floating_point() for p in params)
    return torch.optim.Adam(groups, fused=fused or None, **kwargs)
