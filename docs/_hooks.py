"""MkDocs hooks of the documentation site: the notebooks of `examples/` and the plots of `benchmarks/` are served
beside the pages (the notebooks rendered by mkdocs-jupyter, not executed), each `benchmarks/results_*.md` is a page
of its own, listed on the performance page, and an API page that leaves out a name its package exports fails the
build."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
SERVED = {"examples": "*.ipynb", "benchmarks": "*.png"}
"""Folders of the repository served in the site under the same name, and the files of each."""
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


@event_priority(100)  # before mkdocs-jupyter picks the notebooks up as pages
def on_files(files, config):
    for folder, pattern in SERVED.items():
        for path in sorted((ROOT / folder).glob(pattern)):
            files.append(File(f"{folder}/{path.name}", str(ROOT), config["site_dir"], config["use_directory_urls"]))
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
