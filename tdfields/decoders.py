"""Small MLP heads that turn field features into SDF or colour."""

from __future__ import annotations

import torch
from torch import nn

_ACTIVATIONS = {"tanh": nn.Tanh, "sigmoid": nn.Sigmoid, "relu": nn.ReLU, "softplus": nn.Softplus}


class MLPDecoder(nn.Module):
    """``Linear(in, h) -> ReLU -> (Linear(h, h) -> ReLU) x (hidden_layers - 1) -> Linear(h, out) -> activation``.

    ESLAM/LRSLAM heads: ``MLPDecoder(64, 1, hidden=16, output_activation="tanh")`` (1,329 parameters, the
    normalised TSDF) and ``MLPDecoder(64, 3, hidden=16, output_activation="sigmoid")`` (1,363, RGB).
    PyTorch's default layer initialisation, no positional encoding.

    Args:
        in_dim: feature width in.
        out_dim: output width.
        hidden: hidden units per layer.
        hidden_layers: number of hidden layers (>= 1).
        output_activation: ``"tanh"``, ``"sigmoid"``, ``"relu"``, ``"softplus"`` or ``None``.

    Shapes: ``[..., in_dim] -> [..., out_dim]``.
    """

    def __init__(self, in_dim: int, out_dim: int, hidden: int = 16, hidden_layers: int = 2,
                 output_activation: str | None = None):
        super().__init__()
        if hidden_layers < 1:
            raise ValueError(f"hidden_layers must be >= 1, got {hidden_layers}")
        if output_activation is not None and output_activation not in _ACTIVATIONS:
            raise ValueError(f"output_activation must be one of {sorted(_ACTIVATIONS)} or None, "
                             f"got {output_activation!r}")
        layers: list[nn.Module] = []
        width = in_dim
        for _ in range(hidden_layers):
            layers += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        layers.append(nn.Linear(width, out_dim))
        if output_activation is not None:
            layers.append(_ACTIVATIONS[output_activation]())
        self.net = nn.Sequential(*layers)
        self.in_dim, self.out_dim = in_dim, out_dim

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """``[..., in_dim] -> [..., out_dim]``."""
        return self.net(features)
