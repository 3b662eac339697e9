"""The README and the documentation site's sources: the README's size and set-up commands, no history in the
README, CHANGELOG and pages, links that resolve, the API pages covering every public module, and the README's
benchmark ratios read from the tables it links. Text only (nothing is imported or built): well under a second.
`mkdocs build --strict` (CI, `.ci/run`) checks the site itself; its hook (`docs/_hooks.py`) fails the build when an
API page leaves out a name its module exports."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from test_docstrings import RULES, commit_hashes
from test_imports import MODULES, PUBLIC, _exports

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = sorted((ROOT / "docs").glob("*.md")) + sorted((ROOT / "docs" / "api").glob("*.md"))
README_LIMIT = 8192
"""Bytes the README may hold."""
SETUP = """# jaxrobot

Install and run the whole pipeline on the embedded COMAU Racer-7-1.4 and its virtual test bench:

```bash
pip install . && jaxrobot demo
```

Install and run the tests:

```bash
pip install ".[test]" && python -m pytest
```
"""
"""The README's start: its two set-up commands, unchanged (CI runs the second block's first line)."""
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def test_readme_size_and_setup_commands():
    assert len(README.read_bytes()) <= README_LIMIT, f"README.md: {len(README.read_bytes())} bytes"
    assert README.read_text().startswith(SETUP)


@pytest.mark.parametrize("path", [README, ROOT / "CHANGELOG.md", ROOT / "CONTRIBUTING.md", *PAGES],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history(path):
    """No commit hashes, work-item numbers ("issue 12", "session 6") or past-run labels ("s12-after"): a reader
    can open none of them; history lives in git."""
    text = path.read_text()
    found = [m[0] for m in commit_hashes(text)]
    found += [m[0] for kind in ("work item", "past-run label") for m in RULES[kind].finditer(text)]
    assert not found, f"{path.name}: {found}"


@pytest.mark.parametrize("path", [README, ROOT / "CHANGELOG.md"], ids=lambda p: p.name)
def test_links_resolve(path):
    """Relative links of the files outside the site (the site's own links: `mkdocs build --strict`)."""
    targets = [t for t in LINK.findall(path.read_text()) if not re.match(r"[a-z]+://", t)]
    assert targets or path.name != "README.md"
    assert [t for t in targets if not (path.parent / t).exists()] == []


def test_api_pages_cover_the_public_api():
    """Each public module has one `::: module` directive, on the API page of its package, without a hand-kept
    member list (the hook lists the module's exports); a module a package exports is a public module itself."""
    directives = {}
    for page in sorted((ROOT / "docs" / "api").glob("*.md")):
        text = page.read_text()
        assert "members:" not in text, f"{page.name}: a hand-kept member list"
        for module in re.findall(r"^::: (\S+)\s*$", text, re.M):
            assert module not in directives, f"{module}: on {directives[module]} and {page.name}"
            assert page.stem == module.split(".")[0], f"{module} on {page.name}"
            directives[module] = page.name
    assert sorted(directives) == sorted(PUBLIC)
    exported_modules = {f"{p}.{n}" for p in PUBLIC for n in _exports(p)} & set(MODULES)
    assert exported_modules <= set(PUBLIC)


def _rounds_to(value: str, numbers: list[str]) -> bool:
    """Whether one of `numbers` rounds to `value` at `value`'s decimals."""
    places = len(value.partition(".")[2])
    return any(round(float(n), places) == float(value) for n in numbers)


def test_readme_ratios_are_the_tables():
    """Every ratio (`N×`) of a README line that links a benchmark table is a figure of that table, as rounded."""
    checked = 0
    for line in README.read_text().split("\n- "):
        tables = re.findall(r"\]\((benchmarks/results_\w+\.md)\)", line)
        for ratio in re.findall(r"(\d+(?:\.\d+)?)×", line):
            figures = [n for t in tables for n in re.findall(r"\d+(?:\.\d+)?", (ROOT / t).read_text())]
            assert tables and _rounds_to(ratio, figures), f"README: {ratio}× is in none of {tables}"
            checked += 1
    assert checked >= 4
