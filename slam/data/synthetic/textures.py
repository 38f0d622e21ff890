"""Surface colour: value-noise textures at three scales mixed between each material's two colours, and the fixed
Lambertian shading from the ceiling light. Functions of the 3D world point, so every view sees the same colours.
"""

from __future__ import annotations

import numpy as np

from slam.data.synthetic.scene import SynthScene


def _value_noise(table: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] at points ``p [P, 3]`` (lattice units) from a periodic ``[G, G, G]`` table.

    Trilinear interpolation at smoothstep-warped cell coordinates: C1 across cells, so no grid creases.
    """
    from scipy import ndimage

    f = np.floor(p)
    w = p - f
    q = f + w * w * (3.0 - 2.0 * w)
    return ndimage.map_coordinates(table, q.T, order=1, mode="grid-wrap")


def albedo(scene: SynthScene, p: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """Surface colour ``[P, 3]`` in [0, 1] at world points ``p [P, 3]`` of materials ``mat [P]``."""
    s = scene.scales[mat][:, None].astype(np.float32)
    # a per-material offset decorrelates materials that share a lattice
    q = p.astype(np.float32) * s + mat[:, None].astype(np.float32) * np.array([3.7, 5.3, 1.9], np.float32)
    low = _value_noise(scene.lattice[0], q * 1.6)  # ~60 cm blobs: wide photometric basin
    mid = _value_noise(scene.lattice[1], q * 5.0)  # ~20 cm
    high = _value_noise(scene.lattice[2], q * 14.0)  # ~7 cm detail
    mix = np.clip(0.55 * low + 0.3 * mid + 0.15 * high, 0, 1)
    mix = np.clip((mix - 0.5) * 2.2 + 0.5, 0.0, 1.0)  # more contrast than a plain noise sum
    shade = 0.7 + 0.6 * np.abs(high - 0.5)  # fine brightness detail without another lookup
    col = scene.colors_a[mat] * (1.0 - mix[:, None]) + scene.colors_b[mat] * mix[:, None]
    return np.clip(col * shade[:, None], 0.0, 1.0)


def shade(scene: SynthScene, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    to_l = scene.light - p
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    lam = np.clip((n * to_l).sum(1, keepdims=True) / dist, 0.0, 1.0)
    return 0.45 + 0.75 * lam / (1.0 + 0.08 * dist**2)
