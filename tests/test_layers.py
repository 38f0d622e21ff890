"""The import layers of tdfields and slam (docs/design.md): no import circles, no tdfields -> slam import, and
every module importing only from its own layer or the layers below it.

Imports are read with ``ast`` from the sources, so nothing is executed. Imports inside functions count as
well: a deferred import hides a circle from the interpreter, it does not remove it. Imports under
``if TYPE_CHECKING:`` are left out (they never run). A module added to either package must be placed in
:data:`LAYERS` below, which is the point: its place is a design decision, made once, here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tdfields", "slam")

#: bottom first. A pattern ``pkg.*`` holds every module under ``pkg`` not named exactly in another layer.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("tdfields: leaves", ("tdfields._version", "tdfields.bounds")),
    ("tdfields: functional core (pure PyTorch references)", ("tdfields.interpolation", "tdfields.program")),
    ("tdfields.kernels: shared emitters", ("tdfields.kernels.emitters",)),
    ("tdfields.kernels: per-backend source, numba runtime",
     ("tdfields.kernels.numba", "tdfields.kernels.numba.source", "tdfields.kernels.numba.coords",
      "tdfields.kernels.numba.cells", "tdfields.kernels.triton", "tdfields.kernels.triton.source")),
    ("tdfields.kernels: compile and cache", ("tdfields.kernels.cache",)),
    ("tdfields.kernels: dispatch (backend choice), threads, first-order guard",
     ("tdfields.kernels.dispatch", "tdfields.kernels.threads", "tdfields.kernels.second_order")),
    ("tdfields.kernels: autograd Functions per backend",
     ("tdfields.kernels.numba.autograd", "tdfields.kernels.triton.autograd")),
    ("tdfields.kernels: the face", ("tdfields.kernels",)),
    ("tdfields: ops (kernel or reference, per call)", ("tdfields.ops",)),
    ("tdfields: the Field base class", ("tdfields.field",)),
    ("tdfields: kinds, frozen",
     ("tdfields.dense_grid", "tdfields.triplane", "tdfields.vector_matrix", "tdfields.cp", "tdfields.six_axis",
      "tdfields.frozen", "tdfields.step_scale")),
    ("tdfields: compositions", ("tdfields.multires", "tdfields.hybrid")),
    ("tdfields: configs and build", ("tdfields.config",)),
    ("tdfields: tools over built fields",
     ("tdfields.checkpoint", "tdfields.report", "tdfields.resize", "tdfields.decoders")),
    ("tdfields: the face and its command", ("tdfields", "tdfields.__main__")),
    ("tdfields: integrations with other libraries (each imports its library itself)",
     ("tdfields.integrations", "tdfields.integrations.*")),
    ("slam: leaves", ("slam", "slam._deps", "slam.errors", "slam.files", "slam.data.types")),
    ("slam.core: the functional core (tensors in, tensors out)", ("slam.core", "slam.core.*")),
    ("slam.config: typed configs and presets", ("slam.config", "slam.config.*")),
    ("slam.data: loaders and the synthetic room", ("slam.data", "slam.data.*")),
    ("slam.eval: metrics", ("slam.eval", "slam.eval.*")),
    ("slam.model: the scene model and meshing", ("slam.model", "slam.model.*")),
    ("slam.loop: loop closure (features, verification, the pose graph)", ("slam.loop", "slam.loop.*")),
    ("slam.engine: frames, tracking, mapping, the loop", ("slam.engine", "slam.engine.*")),
    ("slam.run: a run's outputs, checkpoints, a run to a folder, the viewer", ("slam.run", "slam.run.*")),
    ("slam.sweep: sweeps of runs", ("slam.sweep", "slam.sweep.*")),
    ("slam: commands", ("slam.commands", "slam.commands.*", "slam.cli", "slam.__main__")),
]

#: upward imports that are known and owned by another change: (importer, imported) -> what fixes it. The layer
#: test skips them, and fails once one is gone, so the entry goes with the fix.
PENDING: dict[tuple[str, str], str] = {}


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            mods[".".join(parts)] = path
    return mods


MODULES = _modules()


def _ours(name: str) -> str | None:
    """The module of ours that ``import name`` executes last (``pkg.mod.attr`` -> ``pkg.mod``), or None."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def imports_of(module: str) -> list[tuple[str, int, bool]]:
    """``(imported module, line, deferred)`` for every import of one of our modules in ``module``."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[str, int, bool]] = []

    def visit(node: ast.AST, deferred: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(ast.Module(body=[sub], type_ignores=[]), deferred)
                continue
            inner = deferred or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            targets: list[str] = []
            if isinstance(child, ast.Import):
                targets = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    parts = package.split(".")
                    parts = parts[: len(parts) - child.level + 1]
                    base = ".".join(parts + ([base] if base else []))
                # "from pkg import mod" imports the module pkg.mod; "from mod import name" the module mod
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in child.names]
            elif (isinstance(child, ast.Call) and isinstance(child.func, ast.Attribute)
                  and child.func.attr == "import_module" and child.args
                  and isinstance(child.args[0], ast.Constant) and isinstance(child.args[0].value, str)):
                targets = [child.args[0].value]
            for t in targets:
                mod = _ours(t)
                if mod is not None and mod != module:
                    found.append((mod, child.lineno, inner))
            visit(child, inner)

    visit(ast.parse(path.read_text(), str(path)), False)
    return found


GRAPH = {m: imports_of(m) for m in MODULES}


def layer_of(module: str) -> int:
    for i, (_, names) in enumerate(LAYERS):
        if module in names:
            return i
    best = None
    for i, (_, names) in enumerate(LAYERS):
        for pattern in names:
            if pattern.endswith(".*") and module.startswith(pattern[:-1]):
                best = i if best is None else best
    if best is None:
        raise KeyError(module)
    return best


def _where(module: str, line: int) -> str:
    return f"{MODULES[module].relative_to(ROOT)}:{line}"


def test_every_module_has_a_layer():
    unplaced = []
    for m in MODULES:
        try:
            layer_of(m)
        except KeyError:
            unplaced.append(m)
    assert not unplaced, f"place these modules in tests/test_layers.py LAYERS (and docs/design.md): {unplaced}"


def test_tdfields_never_imports_slam():
    bad = [f"{_where(m, line)} imports {t}" for m in MODULES if m.split(".")[0] == "tdfields"
           for t, line, _ in GRAPH[m] if t.split(".")[0] == "slam"]
    assert not bad, bad


def test_imports_point_down_the_layers():
    bad = []
    for m, edges in GRAPH.items():
        for t, line, deferred in edges:
            if layer_of(t) > layer_of(m) and (m, t) not in PENDING:
                bad.append(f"{_where(m, line)}: {m} ({LAYERS[layer_of(m)][0]}) imports {t} "
                           f"({LAYERS[layer_of(t)][0]}){' inside a function' if deferred else ''}")
    assert not bad, "imports up the layers:\n" + "\n".join(bad)


def test_pending_exceptions_are_still_needed():
    stale = [pair for pair in PENDING if pair[1] not in {t for t, _, _ in GRAPH.get(pair[0], [])}]
    assert not stale, f"fixed: remove these from PENDING in tests/test_layers.py: {stale}"


def test_every_named_layer_module_exists():
    named = {n for _, names in LAYERS for n in names if not n.endswith(".*")}
    assert not sorted(named - set(MODULES)), "LAYERS names modules that do not exist"


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


@pytest.mark.parametrize("which", ["module level", "all imports"])
def test_no_import_circles(which):
    edges = {m: {t for t, _, deferred in GRAPH[m] if which == "all imports" or not deferred} for m in MODULES}
    circles = _cycles(edges)
    assert not circles, f"import circles ({which}): {circles}"


def test_the_checker_sees_circles_and_upward_imports():
    """The graph code itself: a circle through a deferred import is found, a downward edge is not one."""
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
    assert layer_of("slam.data.replica") == layer_of("slam.data.base") < layer_of("slam.commands.synth")
    assert layer_of("tdfields") < layer_of("slam")
