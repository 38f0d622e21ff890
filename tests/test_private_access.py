"""No module reads another's private names: ``obj._name`` where ``_name`` is not defined in the same module, and
``from module import _name`` across modules. A private name is a module's own business; what another module needs
gets a public name (or a method on the class that owns the state, e.g. ``state_dict``).

Read with ``ast`` from the sources of both packages (nothing is executed). ``self._x`` / ``cls._x`` are the class's
own; dunders (``__version__``, ``__name__``) are public protocol; ``torch._foreach_*`` and the like are third-party
APIs and listed in :data:`ALLOWED` with the reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tdfields", "slam")

#: ``(module path, attribute)`` pairs that are not a private name of ours: each says why
ALLOWED: dict[tuple[str, str], str] = {
    ("slam/__init__.py", "_deps"): "the package's own dependency probe module, imported before anything else",
    ("slam/cli.py", "_deps"): "the dependency probe: the CLI reports missing packages itself",
}
#: attributes of third-party modules that are their documented (if underscored) API
THIRD_PARTY = {"_foreach_norm": "torch's fused multi-tensor norm", "_foreach_mul_": "torch's fused in-place multiply",
               "_foreach_add_": "torch's fused in-place add", "_foreach_addcmul_": "torch's fused in-place addcmul",
               "_foreach_addcdiv_": "torch's fused in-place addcdiv", "_foreach_sqrt": "torch's fused sqrt",
               "_foreach_lerp_": "torch's fused lerp", "_foreach_div_": "torch's fused division",
               "_foreach_mul": "torch's fused multiply", "_foreach_add": "torch's fused add",
               "_foreach_div": "torch's fused division", "_foreach_sub": "torch's fused subtraction",
               "_foreach_neg": "torch's fused negation",
               "_fused_adam_": "the kernel torch.optim.Adam(fused=True) calls; slam.core.optim.FusedAdam steps it "
                               "(torch.optim where torch lacks it), tested bit for bit against torch.optim",
               "_asdict": "namedtuple's public method", "_replace": "namedtuple's public method",
               "_fields": "namedtuple's public attribute", "_exit": "os._exit (no cleanup after a fork)",
               "_getframe": "sys._getframe", "_scene": "trimesh's Embree intersector keeps its scene there",
               "_current_frames": "sys._current_frames (thread dumps)",
               "_version": "torch.Tensor._version, the in-place version counter a cache checks"}


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _defined_in(tree: ast.AST) -> set[str]:
    """Private names a module defines: functions, classes, assignments (``_x = ``, ``self._x = ``), arguments."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return {n for n in names if _private(n)}


def violations() -> list[str]:
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = str(path.relative_to(ROOT))
            tree = ast.parse(path.read_text(), rel)
            own = _defined_in(tree)
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module != "__future__":
                    for a in node.names:
                        if _private(a.name) and (rel, a.name) not in ALLOWED:
                            out.append(f"{rel}:{node.lineno}: imports the private {a.name} from {node.module}")
                elif isinstance(node, ast.Attribute) and _private(node.attr):
                    base = node.value
                    if isinstance(base, ast.Name) and base.id in ("self", "cls"):
                        continue
                    if isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id == "super":
                        continue
                    if node.attr in own or node.attr in THIRD_PARTY or (rel, node.attr) in ALLOWED:
                        continue
                    out.append(f"{rel}:{node.lineno}: reads {ast.unparse(node)}")
    return out


def test_no_module_reads_another_modules_private_names():
    found = violations()
    assert not found, "private names read across modules:\n" + "\n".join(found)
