"""The cells of a plane that bilinear interpolation at given points reads: hand-written numba (imported lazily by
:mod:`tdfields.kernels.numba.autograd`, needs numba).

A Six-axis sub-plane is composed over the points' bounding box, but a mapping batch reads only a fifth to a third
of its cells (the four corners around each point). :func:`read_cells` marks them, with the lower index the
generated query kernels and :func:`tdfields.interpolation.interpolate_reference` use (truncation of a coordinate
that is never negative, clamped to ``[0, n - 2]``), so the plane can be composed there only.

No ``fastmath``: the non-finite check must see NaN and infinity.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def read_cells(coords, n_a, n_b, live):  # pragma: no cover - compiled
    """``coords [N, 2]`` continuous indices into an ``[n_a, n_b]`` plane -> ``live [n_a * n_b]`` uint8 set to 1 at
    the four cells each point's interpolation reads. Returns False at the first non-finite coordinate (whose
    corners no kernel defines): the caller then composes every cell."""
    for n in range(coords.shape[0]):
        x = coords[n, 0]
        y = coords[n, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            return False
        i = int(x)
        if i > n_a - 2:
            i = n_a - 2
        if i < 0:
            i = 0
        j = int(y)
        if j > n_b - 2:
            j = n_b - 2
        if j < 0:
            j = 0
        row = i * n_b + j
        live[row] = 1
        live[row + 1] = 1
        live[row + n_b] = 1
        live[row + n_b + 1] = 1
    return True
