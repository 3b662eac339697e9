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


def _modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the three packages below `root`, by dotted name (`pkgutil.iter_modules` per
    folder, so that nothing is imported)."""
    out = {}

    def walk(name: str, folder: Path) -> None:
        out[name] = folder / "__init__.py"
        for info in pkgutil.iter_modules([str(folder)]):
            if info.ispkg:
                walk(f"{name}.{info.name}", folder / info.name)
            else:
                out[f"{name}.{info.name}"] = folder / f"{info.name}.py"

    for top in PACKAGES:
        if (root / top).is_dir():
            walk(top, root / top)
    return out


MODULES = _modules()
PUBLIC = ("jaxrobot", "jaxrobot.measurement", "jaxrobot.bench", "jaxrobot.linalg", "jaxrobot.status", "jaxrobot.cli",
          "jaxrobot.checks", "identification", "identification.gear", "identification.calibration",
          "identification.diagnosis", "planning")
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


def _violations(modules: dict[str, Path]) -> list[str]:
    """`path:line: module [names]` of every import of a private module or name of another package."""
    bad = []
    for module, path in modules.items():
        own = module.split(".")[0]
        for line, target, names in _imports(module, path):
            top = target.split(".")[0]
            if top not in PACKAGES or top == own:
                continue
            private = [p for p in target.split(".") if p.startswith("_")] + [n for n in names if n.startswith("_")]
            if private:
                bad.append(f"{path.name}:{line}: {target} {list(names)}")
    return bad


def test_modules_found():
    assert set(PUBLIC) <= set(MODULES)
    assert len(MODULES) > 50


def test_no_private_name_imported_across_packages():
    assert _violations(MODULES) == []


def test_jaxrobot_imports_neither_identification_nor_planning():
    found = [f"{MODULES[m].relative_to(ROOT)}:{line}: {target}" for m in MODULES if m.split(".")[0] == "jaxrobot"
             for line, target, _ in _imports(m, MODULES[m]) if target.split(".")[0] in ("identification", "planning")]
    assert found == []


def test_walk_catches_private_imports(tmp_path):
    """The check itself, on a small tree: a private module and a private name of another package, lazy
    and relative imports; public names, and private ones within a package, pass."""
    (tmp_path / "jaxrobot").mkdir()
    (tmp_path / "jaxrobot" / "__init__.py").write_text("from ._checks import check_public as _check_public\n")
    sub = tmp_path / "identification" / "sub"
    sub.mkdir(parents=True)
    for folder in (tmp_path / "identification", sub):
        (folder / "__init__.py").write_text("")
    (sub / "_x.py").write_text("import jaxrobot as jr\nfrom jaxrobot.bench import gear_runs\n"
                               "from .. import _batched_lm\nfrom jaxrobot._kinematics import rot_x\n"
                               "from jaxrobot import _checks\n"
                               "def f():\n    import planning._ocp\n")
    (tmp_path / "planning").mkdir()
    (tmp_path / "planning" / "__init__.py").write_text("")
    (tmp_path / "planning" / "_ocp.py").write_text("from identification.sub import _x\n")
    modules = _modules(tmp_path)
    assert set(modules) == {"jaxrobot", "identification", "identification.sub", "identification.sub._x", "planning",
                            "planning._ocp"}
    assert _violations(modules) == ["_x.py:4: jaxrobot._kinematics ['rot_x']", "_x.py:5: jaxrobot ['_checks']",
                                    "_x.py:7: planning._ocp []", "_ocp.py:1: identification.sub ['_x']"]


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
