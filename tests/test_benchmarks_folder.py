"""`benchmarks/` holds the benchmark scripts, `_timing.py`, one current results file per script and the
figures and rows the scripts write; every results file starts with the header block of `_timing.header`
(command, commit, machine, device, date, versions, peer of its run)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
SCRIPTS = sorted(p for p in BENCH.glob("*.py") if p.name != "_timing.py")
RESULTS = sorted(BENCH.glob("results_*.md"))
def _timing():
    spec = importlib.util.spec_from_file_location("_timing", BENCH / "_timing.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _results_name(script: Path) -> str:
    """`bench_x.py` -> `x`, `hang_test.py` -> `hang`."""
    return script.stem.removeprefix("bench_").removesuffix("_test")


def test_benchmarks_holds_scripts_their_results_and_the_files_they_name():
    names = {_results_name(s) for s in SCRIPTS}
    sources = {_results_name(s): s.read_text() for s in SCRIPTS}
    stray = []
    for path in BENCH.iterdir():
        if path.name in ("_timing.py", "__pycache__") or path in SCRIPTS:
            continue
        if path.suffix == ".md":
            ok = path.name.startswith("results_") and path.name.removeprefix("results_").removesuffix(".md") in names
        elif path.suffix in (".png", ".json"):  # a figure or rows: named in the source of the script it belongs to
            prefix = path.name.split("_", 1)[0]
            ok = prefix in names and path.name in sources[prefix]
        else:
            ok = False
        if not ok:
            stray.append(path.name)
    assert not stray, f"benchmarks/ holds files that are not a script's current output: {stray}"
    written = {m for text in sources.values() for m in re.findall(r"results_\w+\.md", text)}
    missing = sorted(w for w in written if not (BENCH / w).is_file())
    assert not missing, f"results files named by the scripts but absent: {missing}"
    assert all(re.search(r"results_\w+\.md", text) for text in sources.values()), "a script names no results file"


@pytest.mark.parametrize("path", RESULTS, ids=lambda p: p.name)
def test_results_file_starts_with_the_header_of_its_run(path):
    fields = _timing().HEADER_FIELDS
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# "), f"{path.name}: expected a title on line 1, found {lines[0]!r}"
    head = lines[2:2 + len(fields)]
    found = [line.split(":", 1)[0].removeprefix("- ") for line in head]
    assert found == list(fields), f"{path.name}: expected the header fields {list(fields)} on lines 3-9, found {found}"
    assert all(line.split(":", 1)[1].strip() for line in head), f"{path.name}: a header field is empty"
