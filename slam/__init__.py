"""LRSLAM: dense RGB-D SLAM with low-rank (CP + Six-axis) scene fields, built on :mod:`tdfields`.

Dependency direction is one-way: ``slam`` imports ``tdfields``; ``tdfields`` never imports ``slam``.
"""

from tdfields._version import __version__

__all__ = ["__version__"]
