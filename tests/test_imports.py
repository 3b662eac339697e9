"""The package layout (CONTRIBUTING.md): no private name imported across packages, `jaxrobot`
importing neither `identification` nor `planning`, and every field of the public result types documented.

Reads the sources with `ast` (nothing is imported), so it costs well under a second."""

import ast
import pkgutil
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
PUBLIC = ("jaxrobot", "jaxrobot.measurement", "jaxrobot.io", "jaxrobot.effects", "jaxrobot.bench", "jaxrobot.cli",
          "jaxrobot.internal",
          "identification", "identification.gear", "identification.calibration", "identification.diagnosis",
          "identification.cli", "planning", "planning.internal")
"""The public packages and modules, each with its section in the API reference (`docs/api/`, `tests/test_docs.py`)."""


def _from_module(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute name of the module that a `from ... import` of `module` (at `path`) imports from."""
    base = node.module or ""
    if node.level:
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        parts = package.split(".")
        parts = parts[: len(parts) - node.level + 1]
        base = ".".join(parts + ([base] if base else []))
    return base


def _imports(module: str, path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """`(line, imported module, imported names)` of every import in a module (lazy ones included),
    relative imports resolved."""
    tree = ast.parse(path.read_text(), str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.lineno, _from_module(module, path, node), tuple(a.name for a in node.names)))
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


def _defining_class(modules: dict[str, Path], module: str, name: str,
                    seen: frozenset = frozenset()) -> tuple[str, ast.ClassDef] | None:
    """`(defining module, class)` of the name `name` of `module`: a class defined there, or one it
    imports (`from ._x import Name as Name`), followed through the packages' modules; None for a name
    that is no class of the packages (a function, a constant, a module, a class of another library)."""
    if (module, name) in seen or module not in modules:
        return None
    path = modules[module]
    tree = ast.parse(path.read_text(), str(path))
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == name:
            return module, node
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = _from_module(module, path, node)
            for a in node.names:
                if (a.asname or a.name) == name and f"{base}.{a.name}" not in modules:
                    return _defining_class(modules, base, a.name, seen | {(module, name)})
    return None


def _is_result_type(cls: ast.ClassDef) -> bool:
    """A dataclass (`@dataclasses.dataclass(...)`, `@dataclass`) or an `eqx.Module` (a base ending in
    `Module`)."""
    decorators = [ast.unparse(d.func if isinstance(d, ast.Call) else d) for d in cls.decorator_list]
    return (any(d.split(".")[-1] == "dataclass" for d in decorators)
            or any(ast.unparse(b).endswith("Module") for b in cls.bases))


def _fields_without_docstring(cls: ast.ClassDef) -> list[str]:
    """The annotated fields (`name: type`, `ClassVar`s left out) of a class body that no string literal
    follows."""
    out = []
    for stmt, after in zip(cls.body, [*cls.body[1:], None]):
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        ann = stmt.annotation
        text = ann.value if isinstance(ann, ast.Constant) and isinstance(ann.value, str) else ast.unparse(ann)
        if text.split("[")[0].strip().split(".")[-1] == "ClassVar":
            continue
        if not (isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)):
            out.append(stmt.target.id)
    return out


def _undocumented_fields(modules: dict[str, Path], package: str) -> tuple[list[str], list[str]]:
    """The result types (dataclasses, `eqx.Module`s) that `package` exports, as `module.Class`, and
    `module.Class: [fields]` of those with fields lacking a docstring (CONTRIBUTING.md, "Result types")."""
    tree = ast.parse(modules[package].read_text())
    names = sorted({a.asname for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                    for a in node.names if a.asname and not a.asname.startswith("_")})
    checked, bad = [], []
    for name in names:
        found = _defining_class(modules, package, name)
        if found is None or not _is_result_type(found[1]):
            continue
        module, cls = found
        checked.append(f"{module}.{cls.name}")
        missing = _fields_without_docstring(cls)
        if missing:
            bad.append(f"{module}.{cls.name}: {missing}")
    return checked, bad


@pytest.mark.parametrize("package", PUBLIC)
def test_result_type_fields_have_docstrings(package):
    """Every field of an exported dataclass or `eqx.Module` has a docstring: a string literal on the
    line(s) right after it (CONTRIBUTING.md, "Result types")."""
    _, bad = _undocumented_fields(MODULES, package)
    assert not bad, f"{package} exports types with fields lacking a docstring: " + "; ".join(bad)


def test_field_docstring_check_finds_the_types():
    """The check sees through the re-exports to the classes it must cover."""
    checked = {c for package in PUBLIC for c in _undocumented_fields(MODULES, package)[0]}
    assert {"jaxrobot._robot.Robot", "jaxrobot.measurement._gear_run.GearRun", "jaxrobot.measurement._poses.Poses",
            "planning._workflow.PlanResult",
            "planning._transcription.State", "identification.diagnosis._effects._effect.Effect",
            "identification.calibration._calibrate.CalibrationResult"} <= checked


def test_field_docstring_check(tmp_path):
    """The check itself, on a small tree: re-exports followed through two `__init__`s, dataclasses and
    `eqx.Module`s checked; `ClassVar`s, plain classes, functions and module re-exports left out."""
    pkg = tmp_path / "jaxrobot"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .sub import A as A\nfrom .sub import B as B\nfrom . import sub as sub\n"
                                     "from ._c import C as C\nfrom ._c import D as D\nfrom ._c import f as f\n")
    (pkg / "sub" / "__init__.py").write_text("from ._a import A as A\nfrom ._a import B as B\n")
    (pkg / "sub" / "_a.py").write_text(
        'import dataclasses\nfrom typing import ClassVar\n\n@dataclasses.dataclass(frozen=True)\nclass A:\n'
        '    """A."""\n    x: int\n    """Doc."""\n    y: float = 0.0\n    z: ClassVar[int] = 1\n'
        '    w: str = ""\n\n    def f(self):\n        v: int = 1\n\nclass B:\n    x: int\n')
    (pkg / "_c.py").write_text(
        'import equinox as eqx\nfrom dataclasses import dataclass\n\nclass C(eqx.Module):\n'
        '    a: float\n    """Doc."""\n    b: float\n\n@dataclass\nclass D:\n'
        '    c: "ClassVar[int]"\n    d: int\n    """Doc."""\n\ndef f():\n    pass\n')
    modules = _modules(tmp_path)
    checked, bad = _undocumented_fields(modules, "jaxrobot")
    assert checked == ["jaxrobot.sub._a.A", "jaxrobot._c.C", "jaxrobot._c.D"]
    assert bad == ["jaxrobot.sub._a.A: ['y', 'w']", "jaxrobot._c.C: ['b']"]
