"""The Adam both loops use: PyTorch's fused implementation where the device has one.

Fused Adam updates all parameters in one kernel instead of a dozen tensor ops per parameter: measured here
(1 thread) 3.3 ms vs 13.0 ms per step for ESLAM's 6.79M room0 parameters and 0.36 ms vs 1.26 ms for LRSLAM's
0.86M. It follows the same update rule as the default implementation.

CUDA has had fused Adam since torch 1.13; the CPU kernel arrived in torch 2.4 (pytorch/pytorch#123074), and
older torch raises ``RuntimeError: `fused=True` requires all the params to be floating point Tensors of
supported devices`` for CPU parameters. On torch 2.1-2.3 CPU parameters therefore take the ``foreach``
implementation (same update rule, one multi-tensor op per step stage instead of one kernel).
"""

from __future__ import annotations

import re

import torch

__all__ = ["adam", "fused_devices", "FUSED_CPU_MIN_TORCH", "FusedAdam", "VectorAdam"]

#: first torch release with a fused Adam kernel for CPU tensors
FUSED_CPU_MIN_TORCH = (2, 4)


def _torch_release(version: str) -> tuple[int, int]:
    m = re.match(r"(\d+)\.(\d+)", str(version))
    return (int(m.group(1)), int(m.group(2))) if m else (0, 0)


def fused_devices(version: str | None = None) -> tuple[str, ...]:
    """Device types with a fused Adam kernel in torch ``version`` (default: the installed torch)."""
    release = _torch_release(torch.__version__ if version is None else version)
    return ("cpu", "cuda") if release >= FUSED_CPU_MIN_TORCH else ("cuda",)


def adam(groups: list[dict], reference: bool = False, **kwargs):
    """Adam over ``groups`` (torch parameter groups: ``params`` and ``lr``; ``kwargs``: ``betas``, ``eps``): a
    :class:`FusedAdam` when every parameter is a float tensor on a device with a fused kernel (CUDA; CPU from torch
    2.4), else ``torch.optim.Adam`` with ``foreach`` for float parameters on one kind of device, else the plain one.
    ``reference`` (or any other ``torch.optim.Adam`` keyword): ``torch.optim.Adam``, fused where :class:`FusedAdam`
    would run, the path :class:`FusedAdam` is tested against."""
    params = [p for g in groups for p in g["params"]]
    devices = {p.device.type for p in params}
    floating = bool(params) and all(p.is_floating_point() for p in params)
    if floating and devices <= set(fused_devices()):
        if reference or not hasattr(torch, "_fused_adam_") or set(kwargs) - {"betas", "eps"}:
            return torch.optim.Adam(groups, fused=True, **kwargs)
        return FusedAdam(groups, **kwargs)
    if floating and len(devices) == 1:
        return torch.optim.Adam(groups, foreach=True, **kwargs)
    return torch.optim.Adam(groups, **kwargs)


class FusedAdam:
    """``torch.optim.Adam(groups, fused=True)`` without ``torch.optim``: the same fused kernel
    (``torch._fused_adam_``) on the same state, bit for bit (tested), for the mapper's optimisers.

    ``torch.optim``'s first optimiser in a process imports ``torch._dynamo`` (1.5-1.9 s on the 2-core machines,
    inside the first mapping call, so on every run's critical path), and every step goes through its hooks, grad-mode
    and dynamo-disable wrappers and regroups the tensors. This keeps what the kernel needs: ``param_groups`` (dicts
    with ``params`` and ``lr``), ``state`` (per parameter ``step`` ``[]`` float32 on its device, ``exp_avg``,
    ``exp_avg_sq``: the names and types ``torch.optim.Adam`` uses, so carried moments move between the two),
    ``zero_grad`` and ``step``. No weight decay, amsgrad, maximize or gradient scaling.
    """

    def __init__(self, groups: list[dict], betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param_groups = [dict(g, params=list(g["params"]), betas=betas, eps=eps) for g in groups]
        self.state: dict[torch.Tensor, dict] = {}

    def zero_grad(self, set_to_none: bool = True) -> None:
        for g in self.param_groups:
            for p in g["params"]:
                if set_to_none:
                    p.grad = None
                elif p.grad is not None:
                    p.grad.zero_()

    def _slot(self, p: torch.Tensor) -> dict:
        st = self.state.get(p)
        if not st:  # as torch.optim.Adam's lazy state, created at the parameter's first step
            st = self.state[p] = {"step": torch.zeros((), dtype=torch.float32, device=p.device),
                                  "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                                  "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format)}
        return st

    @torch.no_grad()
    def step(self) -> None:
        for g in self.param_groups:
            # torch.optim.Adam groups a group's tensors by (device, dtype) in order of first appearance
            by_kind: dict[tuple, list] = {}
            for p in g["params"]:
                if p.grad is not None:
                    by_kind.setdefault((p.device, p.dtype), []).append(p)
            beta1, beta2 = g["betas"]
            for ps in by_kind.values():
                slots = [self._slot(p) for p in ps]
                steps = [st["step"] for st in slots]
                torch._foreach_add_(steps, 1)
                torch._fused_adam_(ps, [p.grad for p in ps], [st["exp_avg"] for st in slots],
                                   [st["exp_avg_sq"] for st in slots], [], steps, amsgrad=False, lr=g["lr"],
                                   beta1=beta1, beta2=beta2, weight_decay=0.0, eps=g["eps"], maximize=False,
                                   grad_scale=None, found_inf=None)


class VectorAdam:
    """Adam on one small vector with a learning rate per element: the tracker's 7-number pose.

    The same update as ``torch.optim.Adam`` (no weight decay, no amsgrad), written as a handful of tensor ops.
    ``torch.optim`` spends about as long per step on its bookkeeping (parameter groups, state dicts, dispatch of a
    fused kernel) as one tracking iteration spends on its field queries, for 7 numbers; this does the arithmetic
    only, and keeps everything on the parameter's device (no host synchronisation).

    Args:
        param: ``[N]`` leaf tensor with ``requires_grad``.
        lr: ``[N]`` learning rates (a tensor, or one float for all).
        betas, eps: as ``torch.optim.Adam``.
    """

    def __init__(self, param: torch.Tensor, lr, betas=(0.9, 0.999), eps: float = 1e-8):
        self.param = param
        self.lr = torch.as_tensor(lr, dtype=param.dtype, device=param.device).expand_as(param).clone()
        self.b1, self.b2 = betas
        self.eps = eps
        self.m = torch.zeros_like(param)
        self.v = torch.zeros_like(param)
        self.t = 0

    def zero_grad(self) -> None:
        self.param.grad = None

    @torch.no_grad()
    def step(self) -> None:
        g = self.param.grad
        if g is None:
            return
        self.t += 1
        self.m.mul_(self.b1).add_(g, alpha=1 - self.b1)
        self.v.mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
        step_size = self.lr / (1 - self.b1**self.t)
        denom = (self.v.sqrt() / (1 - self.b2**self.t) ** 0.5).add_(self.eps)
        self.param.sub_(step_size * self.m / denom)
