"""LRSLAM: dense RGB-D SLAM with low-rank (CP + Six-axis) scene fields, built on :mod:`tdfields`.

Dependency direction is one-way: ``slam`` imports ``tdfields``; ``tdfields`` never imports ``slam``.
``slam`` needs the ``slam`` extra (``pip install "tdfields[slam]"``); without it importing ``slam`` raises
:class:`slam.errors.MissingDependencyError`, an ``ImportError`` naming the missing packages.
"""

from slam import _deps
from tdfields._version import __version__

# `lrslam` and `python -m slam` import this package first; they report the missing packages themselves
# (slam.cli.main: one line, exit 2), so only they get past here without the extra
if not _deps.running_cli():
    _missing = _deps.missing_dependencies()
    if _missing:
        from slam.errors import MissingDependencyError

        raise MissingDependencyError(_missing)

__all__ = ["__version__"]
