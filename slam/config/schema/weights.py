"""ESLAM's loss weights, the defaults of ``tracking.weights`` and ``mapping.weights``."""

from __future__ import annotations

from slam.core.losses import LossWeights


def _weights(**weights: float):
    return lambda: LossWeights(**weights)


# the one definition of ESLAM's loss weights (docs/slam.md, Losses); LossWeights itself lives with the losses, one
# weight per term of slam.core.losses.LOSS_TERMS (a term left out here takes its LossWeights default)
TRACKING_WEIGHTS = _weights(fs=10.0, center=200.0, tail=50.0, depth=1.0, color=5.0)
MAPPING_WEIGHTS = _weights(fs=5.0, center=200.0, tail=10.0, depth=0.1, color=5.0)
