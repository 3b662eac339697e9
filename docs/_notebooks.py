"""The executed notebooks and the figures of the documentation site, and when they are current.

The site shows the notebooks of `examples/` with their outputs and the figures of `docs/figures/make_figures.py`,
both made from the code of this checkout into a build folder (`build_dir()`, ignored by git), never committed.
A notebook runs small (`JAXROBOT_EXAMPLES_SMALL=1`, as CI's extended step runs it) in a fresh kernel that
imports this checkout, its plots inline. What is built carries the `stamp` of the code it was made from (the
sources of the three packages, their data and `pyproject.toml`, and the notebook or the figure script): a
stamp that differs from the checkout's marks it stale. Imported by the documentation hook (`docs/_hooks.py`)
and the notebook tests (`tests/integration/test_examples.py`, which save their executed copies here when
`JAXROBOT_DOCS_BUILD` names the build folder); needs neither mkdocs nor JAX.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
FIGURE_SCRIPT = ROOT / "docs" / "figures" / "make_figures.py"
CODE = ("jaxrobot", "identification", "planning")
"""The packages whose sources (every file but bytecode) make up the stamp."""
BUILD_ENV = "JAXROBOT_DOCS_BUILD"
"""Environment variable naming the build folder (default `build/docs` of the checkout)."""
STAMP_KEY = "jaxrobot_docs_stamp"
"""Metadata key of an executed notebook holding its stamp."""
INLINE = "module://matplotlib_inline.backend_inline"
"""The matplotlib backend of the kernel: figures become image outputs of their cells."""


def build_dir() -> Path:
    """The build folder of the site's executed notebooks (`examples/`) and figures (`figures/`)."""
    return Path(os.environ.get(BUILD_ENV) or ROOT / "build" / "docs")


@functools.cache
def _code_digest() -> bytes:
    digest = hashlib.sha256()
    files = [ROOT / "pyproject.toml"]
    for package in CODE:
        files += sorted(p for p in (ROOT / package).rglob("*")
                        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc")
    for path in files:
        digest.update(path.relative_to(ROOT).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.digest()


def stamp(source: Path) -> str:
    """A digest of the code of this checkout and of `source` (a notebook or the figure script)."""
    return hashlib.sha256(_code_digest() + source.read_bytes()).hexdigest()


@contextlib.contextmanager
def _environment(**values: str):
    """`os.environ` with `values` set, restored afterwards (a kernel inherits the environment it starts in)."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def execute(name: str, cwd: Path, timeout: int = 1200):
    """Run `examples/<name>` top to bottom in a fresh kernel, small, in the working folder `cwd`; returns the
    executed notebook (`nbformat.NotebookNode`) stamped with the code it ran. A failing cell raises
    `nbclient.exceptions.CellExecutionError`."""
    import nbclient
    import nbformat

    nb = nbformat.read(EXAMPLES / name, as_version=4)
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    with _environment(JAXROBOT_EXAMPLES_SMALL="1", MPLBACKEND=INLINE, PYTHONPATH=path):
        nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3",
                                resources={"metadata": {"path": str(cwd)}}).execute()
    nb.metadata[STAMP_KEY] = stamp(EXAMPLES / name)
    return nb


def save(nb, name: str) -> Path:
    """Write the executed notebook `nb` of `examples/<name>` to the build folder; returns its path."""
    import nbformat

    path = build_dir() / "examples" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, path)
    return path


def current(name: str) -> Path | None:
    """The executed copy of `examples/<name>` in the build folder when it was made from this checkout's code
    and notebook, else None."""
    import json

    path = build_dir() / "examples" / name
    if not path.is_file():
        return None
    try:
        made = json.loads(path.read_text()).get("metadata", {}).get(STAMP_KEY)
    except ValueError:
        return None
    return path if made == stamp(EXAMPLES / name) else None


def figures_current() -> bool:
    """Whether the build folder's figures were made from this checkout's code and figure script."""
    marker = build_dir() / "figures" / "STAMP"
    return marker.is_file() and marker.read_text().strip() == stamp(FIGURE_SCRIPT)


def mark_figures() -> None:
    """Record that the build folder's figures are those of this checkout."""
    (build_dir() / "figures" / "STAMP").write_text(stamp(FIGURE_SCRIPT) + "\n")
