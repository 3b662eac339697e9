"""MkDocs hooks of the documentation site: the notebooks of `examples/` are served executed, with their outputs, and
the figures of `docs/figures/make_figures.py` as `figures/` (both made from this checkout's code, `docs/_notebooks.py`:
an executed copy or figure older than the code is made again, and one that fails fails the build); the plots of
`benchmarks/` are served beside the pages; each `benchmarks/results_*.md` is a page of its own, listed on the
performance page, showing the plots it names; and an API page that leaves out a name its package exports fails the
build."""

from __future__ import annotations

import ast
import importlib.util
import logging
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
SERVED = {"benchmarks": "*.png"}
"""Folders of the repository served in the site under the same name, and the files of each."""
LOG = logging.getLogger("mkdocs.hooks.jaxrobot")
PLOT = re.compile(r"`(\w+\.png)`")
"""A plot named on a page."""


def _load_notebooks():
    spec = importlib.util.spec_from_file_location("jaxrobot_docs_notebooks", ROOT / "docs" / "_notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


notebooks = _load_notebooks()
RESULTS = "benchmarks/results_*.md"
"""The benchmark tables, each a page `benchmarks/results_<name>.md` of the site."""
RESULTS_LIST = "<!-- benchmark tables -->"
"""Where the performance page lists the benchmark pages."""


def exported_names(module: str, root: Path = ROOT) -> set[str]:
    """Names a public module re-exports (`from ._x import f as f`, `from . import m as m`), read from its source."""
    return {a.asname for node in ast.walk(ast.parse(_source(module, root).read_text()))
            if isinstance(node, ast.ImportFrom) for a in node.names if a.asname and not a.asname.startswith("_")}


def _source(module: str, root: Path = ROOT) -> Path:
    """The file of a module of the repository (`pkg/__init__.py` or `pkg/mod.py`)."""
    base = root.joinpath(*module.split("."))
    return base / "__init__.py" if base.is_dir() else base.with_suffix(".py")


def _is_module(name: str) -> bool:
    base = ROOT.joinpath(*name.split("."))
    return base.is_dir() or base.with_suffix(".py").is_file()


def _log(text: str) -> None:
    LOG.info(text)


def executed_notebooks() -> Path:
    """The build folder with every notebook of `examples/` executed from this checkout's code: a copy that is
    missing or stale is executed now (`docs/_notebooks.py`); a notebook that fails fails the build."""
    for source in sorted(notebooks.EXAMPLES.glob("*.ipynb")):
        if notebooks.current(source.name) is not None:
            _log(f"examples/{source.name}: the executed copy in {notebooks.build_dir()} is current")
            continue
        _log(f"examples/{source.name}: executing (small settings) ...")
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as cwd:
            try:
                nb = notebooks.execute(source.name, Path(cwd))
            except Exception as err:  # noqa: BLE001 - any failure of the notebook fails the build, named
                raise PluginError(f"examples/{source.name} failed to execute: {err}") from err
        notebooks.save(nb, source.name)
        _log(f"examples/{source.name}: executed in {time.perf_counter() - start:.0f} s")
    return notebooks.build_dir()


def figures() -> Path:
    """The build folder's `figures/`, made by `docs/figures/make_figures.py` in a fresh process when missing or
    stale; a failure fails the build."""
    out = notebooks.build_dir() / "figures"
    if notebooks.figures_current():
        _log(f"figures: those in {out} are current")
        return out
    shutil.rmtree(out, ignore_errors=True)
    _log(f"figures: python {notebooks.FIGURE_SCRIPT.relative_to(ROOT)} {out} ...")
    start = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)}
    done = subprocess.run([sys.executable, str(notebooks.FIGURE_SCRIPT), str(out)], env=env, cwd=ROOT)
    if done.returncode != 0:
        raise PluginError(f"{notebooks.FIGURE_SCRIPT.relative_to(ROOT)} failed (exit {done.returncode}); "
                          "its output is above")
    notebooks.mark_figures()
    _log(f"figures: made in {time.perf_counter() - start:.0f} s")
    return out


def on_config(config):
    notebooks._code_digest.cache_clear()  # `mkdocs serve` rebuilds in the same process
    return config


@event_priority(100)  # before mkdocs-jupyter picks the notebooks up as pages
def on_files(files, config):
    def serve(uri: str, src_dir: Path) -> None:
        files.append(File(uri, str(src_dir), config["site_dir"], config["use_directory_urls"]))

    for folder, pattern in SERVED.items():
        for path in sorted((ROOT / folder).glob(pattern)):
            serve(f"{folder}/{path.name}", ROOT)
    built = executed_notebooks()
    for path in sorted(notebooks.EXAMPLES.glob("*.ipynb")):
        serve(f"examples/{path.name}", built)
    for path in sorted(figures().glob("*.png")):
        serve(f"figures/{path.name}", notebooks.build_dir())
    for path in sorted(ROOT.glob(RESULTS)):
        files.append(File.generated(config, f"benchmarks/{path.name}", content=path.read_text()))
    return files


def _title(path: Path) -> str:
    """The first heading of a markdown file, else its name."""
    m = re.search(r"^# (.+)$", path.read_text(), re.M)
    return m.group(1).strip() if m else path.name


def on_page_markdown(markdown, page, config, files):
    """On an API page, `::: module` renders the names the module exports (its submodules have their own
    directive), in the order of the source."""
    if RESULTS_LIST in markdown:
        return markdown.replace(RESULTS_LIST, "\n".join(
            f"- [{_title(p)}]({p.relative_to(ROOT).as_posix()})" for p in sorted(ROOT.glob(RESULTS))))
    if page.file.src_uri.startswith("benchmarks/results_"):
        plots = [name for name in dict.fromkeys(PLOT.findall(markdown)) if (ROOT / "benchmarks" / name).is_file()]
        return markdown + "".join(f"\n\n![{name}]({name})" for name in plots)
    if not page.file.src_uri.startswith("api/"):
        return markdown

    def members(match: re.Match) -> str:
        module = match.group(1)
        names = sorted(n for n in exported_names(module) if not _is_module(f"{module}.{n}"))
        return "\n".join([f"::: {module}", "    options:", "      members:", *(f"      - {n}" for n in names)])

    return re.sub(r"^::: (\S+)$", members, markdown, flags=re.M)


def on_page_content(html, page, config, files):
    if not page.file.src_uri.startswith("api/"):
        return html
    missing = [f"{module}.{name}" for module in re.findall(r"^::: (\S+)", page.markdown, re.M)
               for name in sorted(exported_names(module)) if f'id="{module}.{name}"' not in html]
    if missing:
        raise PluginError(f"{page.file.src_uri}: the API reference leaves out {', '.join(missing)}")
    return html
