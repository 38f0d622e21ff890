"""Size limits that keep the packages readable (issue 22; docs/design.md): no module of either package over
:data:`MAX_MODULE_LINES` lines, no function in ``slam`` over :data:`MAX_FUNCTION_LINES` (docstring included), and at
most :data:`MAX_TOP_MODULES` modules directly in ``slam/`` besides its entry points, so its layers stay folders."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 300
MAX_FUNCTION_LINES = 60
MAX_TOP_MODULES = 8
ENTRY_POINTS = {"__init__.py", "__main__.py", "cli.py", "errors.py", "_deps.py"}


def _sources(pkg: str):
    return sorted((ROOT / pkg).rglob("*.py"))


def test_no_module_over_the_line_limit():
    long = [f"{p.relative_to(ROOT)}: {n}" for pkg in ("tdfields", "slam") for p in _sources(pkg)
            if (n := p.read_text().count("\n")) > MAX_MODULE_LINES]
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split them by what they hold): {long}"


def test_no_slam_function_over_the_line_limit():
    long = []
    for p in _sources("slam"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name}: {n}")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_slam_keeps_its_layers_in_folders():
    top = sorted(p.name for p in (ROOT / "slam").glob("*.py") if p.name not in ENTRY_POINTS)
    assert len(top) <= MAX_TOP_MODULES, f"{len(top)} modules directly in slam/ (put them in a layer's folder): {top}"
