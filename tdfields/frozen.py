"""The one place a field may cache what it derives from its factors: inside :func:`frozen`.

A cache of a result is only correct while its inputs stay as they were. Version counters cannot promise that:
fused and foreach optimizers, ``.data`` edits and custom kernels write parameters without advancing them (the
Six-axis plane cache read a stale map in every SLAM run because of exactly this). So the contract is explicit:

* Outside :func:`frozen` nothing is cached. Every query reads the factors as they are now, whatever wrote them.
* ``with tdfields.frozen(module):`` sets ``requires_grad=False`` on every parameter of ``module`` (restored on
  exit) and lets its fields cache derived tensors (Six-axis: its composed planes) for the duration of the block.
  With gradients off no optimizer step can write the parameters, since every ``torch.optim`` skips parameters
  whose ``grad`` is ``None``. Entering and leaving the block drop every cache, so a block never sees
  what an earlier block derived.

What stays the caller's promise: not to write the parameters in place inside the block (``load_state_dict``,
``.data`` or ``copy_`` under ``no_grad``). ``load_state_dict`` and replaced tensors (``tdfields.resize``,
``.to()``) are still caught by a belt-and-braces check (tensor identity and version counter); ``.data`` edits
inside a block are not.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

from torch import nn

from tdfields.field import Field


def _fields(module: nn.Module) -> list[Field]:
    return [m for m in module.modules() if isinstance(m, Field)]


@contextlib.contextmanager
def frozen(module: nn.Module) -> Iterator[nn.Module]:
    """Freeze ``module`` for the block: no parameter gradients, and its fields may cache derived tensors.

    Coordinates keep their gradients (tracking differentiates the pose through a frozen map). Blocks nest.

    Args:
        module: any ``nn.Module`` holding tdfields fields (a field, a multi-resolution stack, a SLAM scene).

    Yields:
        ``module`` itself.
    """
    flags = [(p, p.requires_grad) for p in module.parameters()]
    fields = _fields(module)
    for p, _ in flags:
        p.requires_grad_(False)
    for f in fields:
        f.clear_cache()
        f._frozen_depth += 1
    try:
        yield module
    finally:
        for f in fields:
            f._frozen_depth -= 1
            f.clear_cache()
        for p, flag in flags:
            p.requires_grad_(flag)
