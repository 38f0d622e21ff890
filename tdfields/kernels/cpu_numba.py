"""The numba runtime behind the fused CPU kernels (imported lazily by :mod:`tdfields.kernels.backend`).

The kernels themselves are generated per program by :mod:`tdfields.kernels.codegen` and compiled by
:mod:`tdfields.kernels.generated`; importing this module is the check that numba works on this machine.
"""

from __future__ import annotations

import numba  # noqa: F401  (the import is the check)
