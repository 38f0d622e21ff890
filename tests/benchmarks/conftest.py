"""What the tests of benchmarks/ share: loading a benchmark script (not a package) as a module."""

import contextlib
import importlib.util
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def load_script(name: str):
    """``benchmarks/<name>.py`` executed as a fresh module named ``name`` (callers that need its sibling modules
    importable put ``BENCHMARKS`` on ``sys.path`` first)."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@contextlib.contextmanager
def script_on_path(name: str):
    """``load_script(name)`` with ``BENCHMARKS`` on ``sys.path`` (its sibling modules importable) while in use."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        yield load_script(name)
    finally:
        sys.path.remove(str(BENCHMARKS))
