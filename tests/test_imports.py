"""The package layout (CONTRIBUTING.md): no private name imported across packages, `jaxrobot`
importing neither `identification` nor `planning`, and the public API listed in the README.

Reads the sources with `ast` (nothing is imported), so it costs well under a second."""

import ast
import pkgutil
import re
from pathlib import Path

import pytest

PACKAGES = ("jaxrobot", "identification", "planning")
ROOT = Path(__file__).resolve().parents[1]


def _modules() -> dict[str, Path]:
    """Every module of the three packages, by dotted name (`pkgutil.iter_modules` per folder, so that
    nothing is imported)."""
    out = {}

    def walk(name: str, folder: Path) -> None:
        out[name] = folder / "__init__.py"
        for info in pkgutil.iter_modules([str(folder)]):
            if info.ispkg:
                walk(f"{name}.{info.name}", folder / info.name)
            else:
                out[f"{name}.{info.name}"] = folder / f"{info.name}.py"

    for top in PACKAGES:
        walk(top, ROOT / top)
    return out


MODULES = _modules()
PUBLIC = ("jaxrobot", "jaxrobot.measurement", "jaxrobot.bench", "jaxrobot.linalg", "jaxrobot.cli", "jaxrobot.checks",
          "identification", "identification.gear", "identification.calibration", "identification.diagnosis", "planning")
"""The public packages and modules, each listed in the README's "Public API"."""


def _imports(module: str, path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """`(line, imported module, imported names)` of every import in a module (lazy ones included),
    relative imports resolved."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            out.append((node.lineno, base, tuple(a.name for a in node.names)))
    return out


def _violations() -> list[str]:
    bad = []
    for module, path in MODULES.items():
        own = module.split(".")[0]
        for line, target, names in _imports(module, path):
            top = target.split(".")[0]
            if top not in PACKAGES or top == own:
                continue
            private = [p for p in target.split(".") if p.startswith("_")] + [n for n in names if n.startswith("_")]
            if private:
                bad.append(f"{path.relative_to(ROOT)}:{line}: {target} {list(names)}")
    return bad


def test_modules_found():
    assert set(PUBLIC) <= set(MODULES)
    assert len(MODULES) > 50


@pytest.mark.xfail(strict=True, reason="imports in the other helpers' files are rewritten after they land")
def test_no_private_name_imported_across_packages():
    assert _violations() == []


def test_jaxrobot_imports_neither_identification_nor_planning():
    found = [f"{MODULES[m].relative_to(ROOT)}:{line}: {target}" for m in MODULES if m.split(".")[0] == "jaxrobot"
             for line, target, _ in _imports(m, MODULES[m]) if target.split(".")[0] in ("identification", "planning")]
    assert found == []


def test_walk_catches_a_private_import(tmp_path):
    """The check itself: a private name from another package, a private module, and a relative import."""
    pkg = tmp_path / "identification" / "sub"
    pkg.mkdir(parents=True)
    (pkg / "_x.py").write_text("from jaxrobot._kinematics import rot_x\nfrom jaxrobot import _checks\n"
                               "from .. import _batched_lm\nimport planning._ocp\n")
    found = _imports("identification.sub._x", pkg / "_x.py")
    assert [(t, n) for _, t, n in found] == [("jaxrobot._kinematics", ("rot_x",)), ("jaxrobot", ("_checks",)),
                                              ("identification", ("_batched_lm",)), ("planning._ocp", ())]


def _exports(package: str) -> set[str]:
    """Names an `__init__` re-exports (`from ._x import f as f`, `from . import m as m`), from its source."""
    tree = ast.parse(MODULES[package].read_text())
    return {a.asname for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
            for a in node.names if a.asname and not a.asname.startswith("_")}


@pytest.mark.parametrize("package", PUBLIC)
def test_readme_lists_the_public_api(package):
    """The README's "Public API" section lists, per package, exactly the names its `__init__` exports."""
    text = (ROOT / "README.md").read_text()
    api = text.split("## Public API", 1)[1].split("\n## ", 1)[0]
    m = re.search(rf"^- \*\*`{re.escape(package)}`\*\*[^\n]*\n((?:  [^\n]*\n)+)", api, re.M)
    assert m, f"README 'Public API': no entry for {package}"
    listed = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", m.group(1)))
    assert listed == _exports(package)
