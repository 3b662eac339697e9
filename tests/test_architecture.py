"""The packages' layering, read from the import statements of every module (module level and inside
functions alike):

- no import circle between modules;
- numeric modules (everything outside a `cli/` folder) import neither argparse nor matplotlib;
- `jaxrobot` imports neither `identification` nor `planning`;
- the identification workflows (`gear`, `calibration`, `diagnosis`) import `identification.core`,
  never each other;
- no module imports a private module (`_name`) of another of the three packages.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("jaxrobot", "identification", "planning")
WORKFLOWS = ("identification.gear", "identification.calibration", "identification.diagnosis")
EDGE_LIBRARIES = ("argparse", "matplotlib")

def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

def _modules() -> dict[str, Path]:
    return {_module_name(path): path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))}

MODULES = _modules()

def _imports(name: str, path: Path) -> set[str]:
    """Every module `name` imports, absolute; `from a import b` counts `a.b` when that is a module."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module
            found.add(source)
            found.update(f"{source}.{alias.name}" for alias in node.names if f"{source}.{alias.name}" in MODULES)
    return found

IMPORTS = {name: _imports(name, path) for name, path in MODULES.items()}

def _own(target: str) -> str | None:
    """The module of these packages that `target` names (its nearest enclosing one), or None."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None

def _is_within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")

def test_no_import_circle():
    graph = {name: {_own(t) for t in targets} - {None, name} for name, targets in IMPORTS.items()}
    # A package's __init__ re-exports its submodules; an edge into a package's own __init__ from inside
    # it is the usual `from . import x` and not a layering circle.
    graph = {name: {t for t in targets if not (MODULES[t].name == "__init__.py" and _is_within(name, t))}
             for name, targets in graph.items()}
    circles, state = [], {}

    def visit(node, stack):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                circles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = "done"

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert not circles, "import circles:\n" + "\n".join(" -> ".join(c) for c in circles)

@pytest.mark.parametrize("library", EDGE_LIBRARIES)
def test_numeric_modules_do_not_import_edge_libraries(library):
    offenders = sorted(name for name, targets in IMPORTS.items()
                       if "cli" not in name.split(".") and any(_is_within(t, library) for t in targets))
    assert not offenders, f"numeric modules importing {library}: {offenders}"

def test_jaxrobot_imports_neither_identification_nor_planning():
    offenders = sorted((name, t) for name, targets in IMPORTS.items() if _is_within(name, "jaxrobot")
                       for t in targets if _is_within(t, "identification") or _is_within(t, "planning"))
    assert not offenders, offenders

def test_workflows_do_not_import_each_other():
    offenders = sorted((name, t) for name, targets in IMPORTS.items() for workflow in WORKFLOWS
                       if _is_within(name, workflow) for t in targets
                       for other in WORKFLOWS if other != workflow and _is_within(t, other))
    assert not offenders, offenders

def test_no_private_import_across_packages():
    offenders = sorted((name, target) for name, targets in IMPORTS.items() for target in targets
                       if target.split(".")[0] in PACKAGES and target.split(".")[0] != name.split(".")[0]
                       and any(part.startswith("_") and not part.startswith("__") for part in target.split(".")))
    assert not offenders, "private modules imported from another package:\n" + "\n".join(
        f"{a} imports {b}" for a, b in offenders)
