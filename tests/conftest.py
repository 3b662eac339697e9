"""Markers beyond the 10-minute suite (2 CPU cores):

- `extended`: an end-to-end check that CI runs after the suite (`.ci/run`, second step); run it with
  `--extended`. Every notebook and README block, and the long integration runs whose parts the suite
  covers one by one.
- `slow`: a long check (full-size OCP solves and sweeps) that CI does not run; `--runslow` runs it
  (and the extended ones).
"""

from __future__ import annotations

import gc
import sys
from pathlib import Path

import pytest

# Tests import `helpers` and each other's module-level helpers by module name (`from test_ocp import _move`),
# across folders and whichever file pytest runs alone: every test folder is on the import path (the test
# files' names are unique across the folders).
TESTS = Path(__file__).resolve().parent
for _folder in ("integration", "planning", "identification", "jaxrobot", ""):
    if str(TESTS / _folder) not in sys.path:
        sys.path.insert(0, str(TESTS / _folder))

# Each program XLA compiles for the CPU maps its code into the process, and the maps stay while JAX's
# caches hold the executable. A test process that compiles thousands of programs (a pytest-xdist worker
# running many files) reaches the kernel's limit on memory maps per process (`vm.max_map_count`, 65530
# by default); XLA's compiler then crashes (SIGSEGV in `backend_compile_and_load`) instead of raising.
# Past half the limit the caches are cleared between tests; later compiles of the same programs come
# from the persistent compilation cache.
_MAPS = Path("/proc/self/maps")
_MAP_LIMIT = Path("/proc/sys/vm/max_map_count")
_CLEAR_ABOVE = int(_MAP_LIMIT.read_text()) // 2 if _MAPS.exists() and _MAP_LIMIT.exists() else None


def _memory_maps() -> int:
    with _MAPS.open() as maps:
        return sum(1 for _ in maps)


def pytest_runtest_teardown(item, nextitem):
    if _CLEAR_ABOVE is not None and _memory_maps() > _CLEAR_ABOVE:
        import jax

        jax.clear_caches()
        gc.collect()


def pytest_addoption(parser):
    parser.addoption("--extended", action="store_true", help="also run the tests marked extended (CI's second step)")
    parser.addoption("--runslow", action="store_true",
                     help="also run the tests marked slow or extended (about 30 min on 2 cores)")


def pytest_report_header(config):
    import sys

    import jax
    import jaxlib

    return f"jaxrobot under Python {sys.version.split()[0]}, jax {jax.__version__}, jaxlib {jaxlib.__version__}"


def pytest_configure(config):
    config.addinivalue_line("markers", "extended: an end-to-end check CI runs after the suite; run with --extended")
    config.addinivalue_line("markers", "slow: a long check (full-size OCP, sweeps); run with --runslow")


# pytest-xdist hands out whole files (`--dist loadfile`) in collection order (`--no-loadscope-reorder`, pyproject's
# addopts), each to the first worker free. These files take longest from a cold compilation cache (minutes each,
# most of it XLA compiling their programs), longest first: started first, they leave the short files to fill both
# workers up to the end, instead of one worker running a long file alone at the end.
LONGEST_FIRST = tuple(TESTS / name for name in (
    "identification/test_calibrate.py", "identification/test_diagnose.py", "planning/test_padding.py",
    "planning/test_front.py", "jaxrobot/test_dynamic_effects.py", "jaxrobot/test_transforms.py",
    "identification/test_identify_gear.py", "jaxrobot/test_simulate.py", "planning/test_al_solver.py",
    "planning/test_cyclic_reduction.py", "planning/test_evaluation.py", "identification/test_calibrate_parallel.py",
    "jaxrobot/test_dynamics.py", "identification/test_runs.py",
    "identification/test_runs_link_drag.py",
))


def _start_rank(item) -> int:
    """The place of an item's file in `LONGEST_FIRST`; the other files after them, in collection order."""
    path = Path(item.path)
    return LONGEST_FIRST.index(path) if path in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_start_rank)  # stable: each file's tests keep their order
    runslow = config.getoption("--runslow")
    extended = runslow or config.getoption("--extended")
    for item in items:
        if "slow" in item.keywords and not runslow:
            item.add_marker(pytest.mark.skip(reason="slow: run with --runslow"))
        elif "extended" in item.keywords and not extended:
            item.add_marker(pytest.mark.skip(reason="extended: run with --extended (CI's second step)"))
