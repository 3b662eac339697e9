"""The built documentation site shows what the tools show: every example notebook with its outputs (no cell left
unexecuted, every cell that plots shows an image, every cell that prints shows its text), every image resolves
to a file of the site or to an image embedded in the page, each page that names a plot (`name.png`) shows it,
and the home page shows the headline figure. Runs on the site folder named by `JAXROBOT_SITE` (CI builds the
site with `mkdocs build --strict`, then runs this file); skipped without it."""

from __future__ import annotations

import base64
import html
import os
import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[2]
SITE = Path(os.environ["JAXROBOT_SITE"]) if os.environ.get("JAXROBOT_SITE") else None
pytestmark = pytest.mark.skipif(SITE is None, reason="no built site: JAXROBOT_SITE names the folder of "
                                "`mkdocs build` (CI sets it after the build)")
NOTEBOOKS = sorted(p.name for p in (ROOT / "examples").glob("*.ipynb"))
PNG = b"\x89PNG\r\n\x1a\n"
HEADLINE = "figures/path_error_as_built.png"
"""The home page's figure: the plan's path error on the as-built robot for the nominal, calibrated and true model."""
PLACEHOLDERS = {"TASK": "line", "RUN": "run"}
"""The placeholders of the plot names the command-line page gives, as its figures are made."""


class _Page(HTMLParser):
    """The images (`src`) of a page and the text of its `<code>` elements."""

    def __init__(self):
        super().__init__()
        self.images: list[str] = []
        self.code: list[str] = []
        self._in_code = 0

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs).get("src") or "")
        elif tag == "code":
            self._in_code += 1
            self.code.append("")

    def handle_endtag(self, tag):
        if tag == "code" and self._in_code:
            self._in_code -= 1

    def handle_data(self, data):
        if self._in_code:
            self.code[-1] += data


def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text())
    return page


def _pages() -> list[Path]:
    return sorted(SITE.rglob("*.html")) if SITE is not None else []


def _image_file(page: Path, src: str) -> Path:
    """The file of the site an image `src` of `page` points to."""
    target = unquote(urlsplit(src).path)
    return (SITE / target.lstrip("/")) if target.startswith("/") else (page.parent / target)


def test_site_was_built():
    assert (SITE / "index.html").is_file(), f"{SITE}: no index.html (not a built site)"
    assert len(_pages()) > 20


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_page_shows_its_outputs(name):
    """Each code cell of the notebook's page is executed (`In [n]:`, never `In [ ]:`); a cell whose source shows
    a plot unconditionally (`plt.show()` at the top level) has an image among its outputs, a cell that prints at
    the top level has output text."""
    import nbformat

    page = SITE / "examples" / Path(name).stem / "index.html"
    assert page.is_file(), f"{page}: the notebook's page is missing"
    text = page.read_text()
    source = [c.source for c in nbformat.read(ROOT / "examples" / name, as_version=4).cells if c.cell_type == "code"]
    # a cell's input prompt opens it (empty for a markdown cell); what follows up to the next one is its outputs
    parts = re.split(r'<div class="jp-InputPrompt jp-InputArea-prompt">([^<]*)</div>', text)[1:]
    cells = [(html.unescape(prompt).replace("\xa0", " "), body) for prompt, body in zip(parts[::2], parts[1::2],
                                                                                       strict=True) if prompt.strip()]
    assert len(cells) == len(source), f"{name}: {len(cells)} code cells on the page, {len(source)} in the notebook"
    for k, (src, (prompt, cell)) in enumerate(zip(source, cells, strict=True)):
        count = re.fullmatch(r"\s*In\s*\[\s*(\d*)\s*\]:\s*", prompt)
        assert count and count.group(1), f"{name} cell {k + 1}: not executed (prompt {prompt!r})"
        if re.search(r"^plt\.show\(\)", src, re.M):
            assert "<img" in cell, f"{name} cell {k + 1}: plots, but its output shows no image"
        if re.search(r"^print\(", src, re.M):
            assert "jp-OutputArea-output" in cell, f"{name} cell {k + 1}: prints, but shows no output"


def test_every_image_resolves():
    """An `<img>` of any page is a PNG of the site or one embedded in the page (`data:image/png;base64`)."""
    checked, broken = 0, []
    for page in _pages():
        for src in _parse(page).images:
            checked += 1
            if src.startswith("data:"):
                head, _, data = src.partition(",")
                ok = head.endswith(";base64") and base64.b64decode(data)[:8] == PNG if head.startswith(
                    "data:image/png") else bool(data)
            elif re.match(r"[a-z]+://", src):
                ok = False  # the site shows no image from elsewhere
            else:
                target = _image_file(page, src)
                ok = target.is_file() and target.stat().st_size > 0
            if not ok:
                broken.append(f"{page.relative_to(SITE)}: {src[:80]}")
    assert checked > 0
    assert broken == []


def test_each_page_that_names_a_plot_shows_it():
    """A page whose text names a plot file (`name.png`, the command-line page's `TASK_*`/`RUN_*` as drawn
    there) has an image of that file."""
    named = 0
    missing = []
    for page in _pages():
        parsed = _parse(page)
        shown = {Path(unquote(urlsplit(src).path)).name for src in parsed.images if not src.startswith("data:")}
        for code in parsed.code:
            for plot in re.findall(r"\b([A-Za-z]\w*\.png)\b", code):
                head, _, rest = plot.partition("_")
                name = f"{PLACEHOLDERS[head]}_{rest}" if head in PLACEHOLDERS else plot
                named += 1
                if name not in shown:
                    missing.append(f"{page.relative_to(SITE)}: {plot}")
    assert named >= 20, named
    assert missing == []


def test_home_page_shows_the_headline_figure():
    srcs = _parse(SITE / "index.html").images
    assert any(src.endswith(HEADLINE) for src in srcs), srcs
    assert (SITE / HEADLINE).stat().st_size > 10_000
