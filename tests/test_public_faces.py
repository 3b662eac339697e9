"""The public faces: what each public package and module exports, counted, and one public path per name.

`python tests/test_public_faces.py` prints the table of counts (the coordinator's and CONTRIBUTING's
before/after table); it imports the packages found on `sys.path`, so it counts any checkout."""

from __future__ import annotations

import importlib
import inspect
import types
import typing
import warnings

import pytest

PUBLIC = ("jaxrobot", "jaxrobot.measurement", "jaxrobot.io", "jaxrobot.effects", "jaxrobot.bench", "jaxrobot.cli",
          "jaxrobot.internal",
          "jaxrobot.linalg", "jaxrobot.status", "jaxrobot.checks", "identification", "identification.gear",
          "identification.calibration", "identification.diagnosis", "planning", "planning.internal")
"""Every module that is or was public; one that a checkout lacks is left out of the count."""

ROOT_BUDGET = {"jaxrobot": 70, "identification": 20, "planning": 50}
"""The most names a package root exports (optimistix exports about 60)."""


def face(module: types.ModuleType) -> dict[str, object]:
    """The names a module exports: its namespace without `_` names, submodules and imported modules
    (deprecated aliases, served by the module's `__getattr__`, are not in the namespace)."""
    return {k: v for k, v in vars(module).items() if not k.startswith("_") and not isinstance(v, types.ModuleType)}


def faces() -> dict[str, dict[str, object]]:
    """`face` of each module of `PUBLIC` that can be imported."""
    out = {}
    for name in PUBLIC:
        try:
            out[name] = face(importlib.import_module(name))
        except ImportError:
            continue
    return out


def _shared(found: dict[str, dict[str, object]]) -> dict[str, list[str]]:
    """`module.name` paths that reach one object from more than one public module, by object (numbers,
    strings and `None`, equal by value rather than identity, are left out)."""
    paths: dict[int, list[str]] = {}
    for module, names in found.items():
        for name, obj in names.items():
            if not isinstance(obj, (int, float, str, type(None))):
                paths.setdefault(id(obj), []).append(f"{module}.{name}")
    return {p[0]: p for p in paths.values() if len(p) > 1}


@pytest.fixture(scope="module")
def found():
    return faces()


def test_one_public_path_per_name(found):
    assert _shared(found) == {}


@pytest.mark.parametrize("root", sorted(ROOT_BUDGET))
def test_package_roots_stay_small(found, root):
    assert 10 <= len(found[root]) <= ROOT_BUDGET[root], sorted(found[root])


def test_old_infrastructure_modules_export_nothing(found):
    """`jaxrobot.linalg`, `.status`, `.checks` hold only deprecated aliases of `jaxrobot.internal`."""
    assert {m: found[m] for m in ("jaxrobot.linalg", "jaxrobot.status", "jaxrobot.checks")} == dict.fromkeys(
        ("jaxrobot.linalg", "jaxrobot.status", "jaxrobot.checks"), {})


@pytest.mark.parametrize("module", ["jaxrobot", "identification", "identification.gear", "planning"])
def test_dir_lists_the_face(found, module):
    assert dir(importlib.import_module(module)) == sorted(found[module])


@pytest.mark.parametrize(("old", "new"), [
    ("jaxrobot.cached_program", "jaxrobot.internal.cached_program"),
    ("jaxrobot.linalg.spd_solve", "jaxrobot.internal.spd_solve"),
    ("jaxrobot.status.check", "jaxrobot.internal.check"),
    ("jaxrobot.checks.check_public", "jaxrobot.internal.check_public"),
    ("planning.defects", "planning.internal.defects"),
    ("planning.cyclic_reduction", "planning.internal.cyclic_reduction"),
    ("identification.detmax", "identification.calibration.detmax"),
    ("identification.calibration.calibrate", "identification.calibrate"),
    ("identification.gear.identify_gear", "identification.identify_gear"),
])
def test_alias_warns_and_returns_the_moved_object(old, new):
    module, _, name = old.rpartition(".")
    new_module, _, new_name = new.rpartition(".")
    with pytest.warns(DeprecationWarning, match=rf"^{old} moved to {new}; the old name goes in the next release$"):
        obj = getattr(importlib.import_module(module), name)
    assert obj is getattr(importlib.import_module(new_module), new_name)
    assert name not in dir(importlib.import_module(module))


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="module 'planning' has no attribute 'defect'"):
        importlib.import_module("planning").defect  # noqa: B018


def _functions(found):
    """`(module.name, signature)` of every public function and class (their constructors) of the faces."""
    out = []
    for module, names in found.items():
        for name, obj in names.items():
            if callable(obj):
                try:
                    out.append((f"{module}.{name}", inspect.signature(obj)))
                except (TypeError, ValueError):
                    continue
    return out


def test_throw_defaults_to_false_everywhere(found):
    throws = {path: sig.parameters["throw"].default for path, sig in _functions(found) if "throw" in sig.parameters}
    assert "jaxrobot.measurement.rest_link_angles" in throws and "planning.solve_ocp" in throws
    assert {path: d for path, d in throws.items() if d not in (False, inspect.Parameter.empty)} == {}


def test_on_event_is_the_one_callback_name(found):
    """A callback is `on_event=`; `progress=` survives only as the deprecated old name beside it."""
    named = {path: set(sig.parameters) & {"on_event", "progress", "callback"} for path, sig in _functions(found)}
    assert {p for p, s in named.items() if s and "on_event" not in s} == set()
    assert {p for p, s in named.items() if "progress" in s} == {"identification.diagnose",
                                                                 "identification.diagnosis.diagnose_runs"}


@pytest.mark.parametrize("workflow", ["identification.diagnose", "identification.diagnosis.diagnose_runs"])
def test_progress_is_the_deprecated_name_of_on_event(workflow):
    """Both names at once is an error, before any work; `progress=` alone warns (and then the empty
    measurements are rejected, which shows the call went on)."""
    module, _, name = workflow.rpartition(".")
    fn = getattr(importlib.import_module(module), name)
    import jaxrobot as jr

    robot = jr.racer7()
    extra = {"instruments": jr.racer7_instruments()} if name == "diagnose" else {"marker": None, "noise": None}
    with pytest.raises(ValueError, match="`progress=` is the old name of `on_event=`"):
        fn(robot, [], [], on_event=print, progress=print, **extra)
    with pytest.warns(DeprecationWarning, match=rf"^{name}\(progress=...\) is now {name}\(on_event=...\); the old"):
        with pytest.raises((ValueError, AttributeError, TypeError)):
            fn(robot, [], [], progress=print, **extra)


RESULT_TYPES = ("identification.CalibrationResult", "identification.FleetResult", "identification.DiagnoseResult",
                "identification.GearIdentification", "planning.OCPSolution", "planning.PlanResult",
                "planning.SweepResult", "planning.SweepCost")


@pytest.mark.parametrize("path", RESULT_TYPES)
def test_every_result_carries_a_results_status(path):
    """`status` of each workflow and solver result is a `jaxrobot.RESULTS` (per cost variant for a sweep), as a
    field or a property; names for JSON and tables come from `jaxrobot.status_name`."""
    import jaxrobot as jr

    module, _, name = path.rpartition(".")
    cls = getattr(importlib.import_module(module), name)
    attr = inspect.getattr_static(cls, "status", None)
    hint = (typing.get_type_hints(attr.fget, vars(importlib.import_module(attr.fget.__module__)))["return"]
            if isinstance(attr, property) else typing.get_type_hints(cls)["status"])
    assert hint is jr.RESULTS or typing.get_args(hint) == (str, jr.RESULTS), hint


@pytest.mark.parametrize(("verdict", "expected"), [
    ("no significant discrepancy: the model explains the data to the noise floor", "successful"),
    ("explained: residuals at the noise floor after adding ripple1", "successful"),
    ("not explained: training residuals at the noise floor, but the validation RMS ...", "inconsistent"),
    ("discrepancy remains after 6 effects (max_steps)", "inconsistent"),
])
def test_diagnose_status_follows_the_verdict(verdict, expected):
    import jaxrobot as jr
    from identification import DiagnoseResult

    res = object.__new__(DiagnoseResult)
    object.__setattr__(res, "verdict", verdict)
    assert jr.status_name(res.status) == expected and res.converged == (expected == "successful")


if __name__ == "__main__":
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        counts = {m: len(names) for m, names in faces().items()}
    for module, n in counts.items():
        print(f"| `{module}` | {n} |")
    print(f"| all | {sum(counts.values())} |")
    print(f"| reachable from two public paths | {len(_shared(faces()))} |")
