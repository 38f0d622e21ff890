"""The SLAM client's own dependencies, checked before anything imports them.

``pip install tdfields`` installs the field library alone; ``slam`` needs the ``slam`` extra. Without it,
``import slam`` raises :class:`slam.errors.MissingDependencyError` (an ``ImportError``) whose one-line message
names the missing packages and the install command, and ``lrslam`` prints that line and exits with 2.

Standard library only: this module must import when the extra is missing.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

__all__ = ["SLAM_REQUIREMENTS", "missing_dependencies", "install_command", "missing_message", "running_cli"]

#: import name -> distribution name of every package the ``slam`` extra installs that ``slam`` needs to import
#: (embreex is in the extra too, but slam.eval falls back to trimesh's own ray caster without it);
#: tests/slam/test_deps.py checks this against pyproject.toml
SLAM_REQUIREMENTS: dict[str, str] = {
    "trimesh": "trimesh",
    "skimage": "scikit-image",
    "scipy": "scipy",
    "tqdm": "tqdm",
    "matplotlib": "matplotlib",
    "imageio": "imageio",
}


def _importable(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a broken or half-removed package: as good as missing
        return False


def missing_dependencies() -> list[str]:
    """Distribution names of the SLAM requirements that cannot be imported, in :data:`SLAM_REQUIREMENTS` order."""
    return [dist for mod, dist in SLAM_REQUIREMENTS.items() if not _importable(mod)]


def install_command(extra: str = "slam") -> str:
    """The command that installs an extra (``slam``, ``viewer``, ``sweep``...) for this installation of the package.

    From a source checkout (editable install, or run from the repository) that is
    ``python3 -m pip install -e "<checkout>[slam]"``; from a wheel, ``python3 -m pip install "tdfields[slam]"``.
    """
    root = Path(__file__).resolve().parents[1]
    if (root / "pyproject.toml").is_file() and (root / "tdfields").is_dir():
        return f'python3 -m pip install -e "{root}[{extra}]"'
    return f'python3 -m pip install "tdfields[{extra}]"'


def missing_message(missing: list[str]) -> str:
    """One line: what is missing and how to install it."""
    names = ", ".join(missing)
    return (f"the SLAM client (slam, lrslam) needs {names}, not installed (tdfields alone does not); "
            f"install the slam extra: {install_command()}")


# the file name the pip/distlib console-script wrapper runs under, without its Windows suffixes
_SCRIPT_SUFFIX = re.compile(r"(-script\.pyw?|\.exe)?$")


def running_cli() -> bool:
    """True while ``lrslam`` or ``python -m slam`` starts up.

    Both import the ``slam`` package before :func:`slam.cli.main` can run, so ``slam/__init__.py`` lets the
    import through when this is true and ``main`` reports the missing packages as one line with exit code 2
    instead of a traceback.
    """
    script = _SCRIPT_SUFFIX.sub("", re.split(r"[\\/]", sys.argv[0])[-1]) if sys.argv and sys.argv[0] else ""
    if script == "lrslam":
        return True
    argv = list(getattr(sys, "orig_argv", []))
    i = 1
    while i < len(argv):
        arg = argv[i]
        if arg == "-m":
            return i + 1 < len(argv) and argv[i + 1] in ("slam", "slam.cli")
        if arg.startswith("-m"):
            return arg[2:] in ("slam", "slam.cli")
        if arg in ("-X", "-W"):  # interpreter options that take a value
            i += 2
            continue
        if arg.startswith("-c") or arg == "-" or not arg.startswith("-"):  # code or a script runs, not slam
            return False
        i += 1
    return False
