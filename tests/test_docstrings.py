"""Docstrings and comments state behaviour (CONTRIBUTING.md, "Rules"): no work-item numbers, commit hashes,
past-run labels or speed claims in the packages' docstrings and comments. Performance figures live in
`benchmarks/results_*.md`, history in git.

The packages are read as text (`ast` for docstrings, `tokenize` for comments), not imported."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("jaxrobot", "identification", "planning")

_HEX = re.compile(r"(?<![\w.])[0-9a-f]{7,40}(?![\w.])")
RULES = {
    "work item": re.compile(r"\b(?:(?:issue|session)s?|item)\s*#?\d+|\bwork items?\b", re.IGNORECASE),
    "past-run label": re.compile(r"\bs\d{1,3}-[a-z][\w-]*|\bafter-merge\b", re.IGNORECASE),
    "speed claim": re.compile(
        r"\b\d+(?:\.\d+)?\s*(?:x|×)\s+(?:faster|slower|quicker|the (?:run|compile|solve) time)"
        r"|\btimes\s+(?:faster|slower|quicker)\b|\bspeed-?ups?\b"
        r"|\b(?:takes?|took|runs? in)\s+~?\d+(?:\.\d+)?\s*(?:ns|µs|us|ms|s|min)\b"
        r"|\b\d+(?:\.\d+)?\s*(?:ns|µs|us|ms|s)\s+instead of\b", re.IGNORECASE),
    "story": re.compile(r"\bwe (?:tried|measured|saw|found|used)\b|\bfailed that way\b", re.IGNORECASE),
}
"""What a docstring or comment must not hold, by kind (commit hashes: `commit_hashes`)."""


def commit_hashes(text: str) -> list[re.Match]:
    """Tokens of 7-40 lower-case hex digits with a digit and a letter, as a commit hash is written; not
    `0x` constants, not decimal exponents like `1e10000`."""
    return [m for m in _HEX.finditer(text) if re.search(r"\d", m[0]) and re.search(r"[a-f]", m[0])
            and not re.fullmatch(r"\d+e\d+", m[0]) and text[max(0, m.start() - 2):m.start()] != "0x"]


def texts(source: str) -> list[tuple[int, str]]:
    """(first line, text) of every docstring (of a module, class, function or attribute) and comment."""
    found = []
    for node in ast.walk(ast.parse(source)):
        body = getattr(node, "body", None)
        for st in body if isinstance(body, list) else []:
            if isinstance(st, ast.Expr) and isinstance(st.value, ast.Constant) and isinstance(st.value.value, str):
                found.append((st.lineno, st.value.value))
    found += [(t.start[0], t.string) for t in tokenize.generate_tokens(io.StringIO(source).readline)
              if t.type == tokenize.COMMENT]
    return found


def findings(source: str, name: str) -> list[str]:
    """`name:line: kind: 'match'` for every rule a docstring or comment of `source` breaks."""
    out = []
    for line, text in texts(source):
        matches = [(kind, m) for kind, rule in RULES.items() for m in rule.finditer(text)]
        matches += [("commit hash", m) for m in commit_hashes(text)]
        out += [f"{name}:{line + text[:m.start()].count(chr(10))}: {kind}: {m[0]!r}" for kind, m in matches]
    return sorted(out)


PLANTED = '''"""Module docstring.

The JSON summary of issue 4, in the order of issue 6, item 7 (session 12).
"""

X = 1
"""4.8x faster than reversing the mass matrix; 17 times faster than before."""


def f():
    """A work item of the board: see 66cc01c for the fix."""
    # the solve takes 5.5 ms; a speed-up of 5
    x = 0  # a scan step: 53 ms instead of 41 ms
    return x  # s12-before and after-merge runs; we tried a scan


class C:
    """Compare the s9-final startup (2.0x slower)."""
'''

CLEAN = '''"""Behaviour only.

Every item of a batch carries its own status; one bench session holds the poses. A solver issues
no warning. Thesis Table 3.8, eq. 4.3 and section 2.1; 17x fewer flops than the dense product.
"""

MASK = 0x3ff0000000000000  # the float64 bits of 1.0, 0x3ff0000000000000
"""Decimal exponents are no hashes: 1e10000, 2e3; words of hex letters neither: facade, decade."""


def g():
    """RK4 steps per 1 ms sample (h = 0.1 ms); rests of 0.2 s; runs before and after the motion."""
    # the first item of the list, `s2` and `s16` as names
    return MASK
'''


def test_the_matcher_finds_each_kind_at_its_line():
    found = findings(PLANTED, "planted.py")
    assert found == sorted([
        "planted.py:3: work item: 'issue 4'",
        "planted.py:3: work item: 'issue 6'",
        "planted.py:3: work item: 'item 7'",
        "planted.py:3: work item: 'session 12'",
        "planted.py:7: speed claim: '4.8x faster'",
        "planted.py:7: speed claim: 'times faster'",
        "planted.py:11: work item: 'work item'",
        "planted.py:11: commit hash: '66cc01c'",
        "planted.py:12: speed claim: 'takes 5.5 ms'",
        "planted.py:12: speed claim: 'speed-up'",
        "planted.py:13: speed claim: '53 ms instead of'",
        "planted.py:14: past-run label: 's12-before'",
        "planted.py:14: past-run label: 'after-merge'",
        "planted.py:14: story: 'we tried'",
        "planted.py:18: past-run label: 's9-final'",
        "planted.py:18: speed claim: '2.0x slower'",
    ])


def test_the_matcher_passes_legitimate_text():
    assert findings(CLEAN, "clean.py") == []


@pytest.mark.parametrize("package", PACKAGES)
def test_docstrings_and_comments_state_behaviour(package):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, f"no Python files under {ROOT / package}"
    found = [f for path in files for f in findings(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))]
    assert not found, ("docstrings and comments state behaviour (performance figures go to benchmarks/, "
                       "history to git):\n" + "\n".join(found))
