"""Self-describing checkpoints: config + state_dict + library version, loadable without the training code."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import nn

from tdfields._version import __version__
from tdfields.config import build

FORMAT = "tdfields-checkpoint/1"


def _spec_of(module: nn.Module) -> dict | None:
    spec = getattr(module, "spec", None)
    return spec() if callable(spec) else None


def save(path: str | Path, module: nn.Module, config: dict | None = None, extra: dict | None = None) -> Path:
    """Write ``{format, version, spec, config, state_dict, extra}`` with ``torch.save``.

    Args:
        path: output file.
        module: a field / multi-resolution / hybrid (its ``spec()`` is stored so :func:`load_field` can rebuild
            it, with its *current* box and grid), or any module (then only ``config`` describes it).
        config: the application's own config (plain, YAML-able data), stored as-is.
        extra: anything else picklable by ``torch.save`` with ``weights_only`` (tensors, numbers, strings, lists).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": FORMAT, "version": __version__, "spec": _spec_of(module), "config": config,
               "state_dict": {k: v.detach().cpu() for k, v in module.state_dict().items()}, "extra": extra or {}}
    torch.save(payload, path)
    return path


def load(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint written by :func:`save` (safely: ``weights_only=True``).

    Raises:
        FileNotFoundError: no such file. ValueError: not a tdfields checkpoint (the message names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises several types for corrupt files
        raise ValueError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path}: not a tdfields checkpoint (missing format tag {FORMAT!r})")
    return payload


def load_field(path: str | Path, map_location: str | torch.device = "cpu") -> nn.Module:
    """Rebuild the field / multi-resolution / hybrid module saved at ``path`` and load its weights."""
    payload = load(path, map_location)
    if payload["spec"] is None:
        raise ValueError(f"{path}: the saved module has no field spec; rebuild it from payload['config']")
    module = build(payload["spec"])
    module.load_state_dict(payload["state_dict"])
    return module.to(map_location)
