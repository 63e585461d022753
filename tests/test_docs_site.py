"""The documentation site builds, every notebook page shows its figures, and no internal link is broken.

Builds the site as README's "Documentation" section says (``MARLANDER_BUDGET=small mkdocs build``), from the
notebooks as the notebook tests executed them (``conftest.executed_notebook``: each runs once per session, and
``MARLANDER_DOCS_NOTEBOOKS`` hands the executed copies to mkdocs-jupyter), then opens the notebook pages in
headless Chromium and decodes the output images of the DOM it built. Links are checked on the built HTML: every
``href`` and ``src`` that stays inside the site must name a file that exists. Chromium is Debian's ``chromium``
package (``.ci/run`` installs it when it can); without it the figure check is skipped, the link check still runs.

One test function builds once and checks everything, so that ``pytest -n 2`` never builds twice.
"""

from __future__ import annotations

import base64
import importlib.util
import io
import os
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
BUILD_TIMEOUT_S = 1800
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def find_chromium() -> str | None:
    """The first headless-capable Chromium on ``PATH``, or ``None``."""
    return next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)


def plotting_notebooks() -> list[str]:
    """Notebooks whose code makes figures (matplotlib or the library's plotting helpers)."""
    pattern = re.compile(r"\bplt\.|\bplot_\w+\(|\bfigures\.")
    return [
        nb_path.stem
        for nb_path in NOTEBOOKS
        if any(
            cell.cell_type == "code" and pattern.search(cell.source)
            for cell in nbformat.read(nb_path, as_version=4).cells
        )
    ]


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if name in ("href", "src") and value:
                self.links.append(value)


def broken_links(site: Path) -> list[str]:
    """``"page -> link"`` for every relative link of every built page whose target file is missing."""
    broken = []
    for page in sorted(site.rglob("*.html")):
        if page.name == "404.html" and page.parent == site:
            continue  # served for any missing URL, so mkdocs writes its links from the server root
        parser = _Links()
        parser.feed(page.read_text(encoding="utf-8"))
        for link in parser.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or not parts.path:  # external, data:, mailto:, "#anchor"
                continue
            base = site if parts.path.startswith("/") else page.parent
            target = (base / unquote(parts.path).lstrip("/")).resolve()
            if target.is_dir():
                target = target / "index.html"
            if not target.is_relative_to(site.resolve()) or not target.is_file():
                broken.append(f"{page.relative_to(site)} -> {link}")
    return broken


DATA_IMAGE = re.compile(r'<img[^>]*\bsrc="data:image/(png|jpeg);base64,([^"]+)"')


def rendered_images(chromium: str, page: Path) -> dict[str, int]:
    """Output images (``data:`` PNG/JPEG) in the DOM Chromium built for a page, and how many decode to a width > 0.

    Chromium opens the page headless, with every host name unresolvable (the build must not need the network:
    external fonts and scripts fail at once), and dumps the DOM it built; Pillow decodes each embedded image.
    """
    from PIL import Image

    command = [
        chromium,
        "--headless",
        "--no-sandbox",  # CI runs as root
        "--disable-gpu",
        "--host-resolver-rules=MAP * ~NOTFOUND",
        "--virtual-time-budget=5000",
        "--dump-dom",
        page.as_uri(),
    ]
    dom = subprocess.run(command, capture_output=True, text=True, timeout=180, check=True).stdout
    assert "</html>" in dom, f"Chromium did not render {page}"
    images = DATA_IMAGE.findall(dom)
    decoded = 0
    for _, data in images:
        with Image.open(io.BytesIO(base64.b64decode(data))) as image:
            image.load()
            decoded += image.width > 0
    return {"images": len(images), "decoded": decoded}


def test_the_link_check_finds_a_broken_link(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "index.html").write_text(
        '<a href="../b/">b</a> <img src="../img.png"> <a href="https://example.org">x</a> <a href="#top">t</a>'
    )
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "index.html").write_text('<a href="../a/index.html#x">a</a> <a href="/b/">b</a>')
    assert broken_links(tmp_path) == ["a/index.html -> ../img.png"]


def test_the_site_hook_takes_executed_copies_only_when_every_notebook_has_one(tmp_path, monkeypatch):
    pytest.importorskip("mkdocs", reason="the docs extra is not installed (pip install -r environment.lock)")
    spec = importlib.util.spec_from_file_location("mkdocs_hooks", ROOT / "scripts" / "mkdocs_hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    monkeypatch.delenv("MARLANDER_DOCS_NOTEBOOKS", raising=False)
    assert hooks.executed_copies() is None  # the repository's notebooks, executed by mkdocs-jupyter
    elsewhere = tmp_path / "executed"
    elsewhere.mkdir()
    monkeypatch.setenv("MARLANDER_DOCS_NOTEBOOKS", str(elsewhere))
    with pytest.raises(ValueError, match="must be named 'notebooks'"):
        hooks.executed_copies()
    folder = tmp_path / "notebooks"
    folder.mkdir()
    for nb_path in NOTEBOOKS[1:]:
        (folder / nb_path.name).write_text("{}")
    monkeypatch.setenv("MARLANDER_DOCS_NOTEBOOKS", str(folder))
    with pytest.raises(FileNotFoundError, match=re.escape(NOTEBOOKS[0].name)):
        hooks.executed_copies()
    (folder / NOTEBOOKS[0].name).write_text("{}")
    assert hooks.executed_copies() == [folder / nb_path.name for nb_path in NOTEBOOKS]


@pytest.mark.slow
@pytest.mark.notebooks
def test_site_builds_shows_every_figure_and_has_no_broken_link(tmp_path, executed_notebook):
    pytest.importorskip("mkdocs_jupyter", reason="the docs extra is not installed (pip install -r environment.lock)")
    site = tmp_path / "site"
    # Newest notebooks first: the notebook tests on another worker usually start from the oldest, so that the two
    # run different notebooks at the same time instead of one waiting for the other's run.
    copies = [executed_notebook(nb_path.name) for nb_path in reversed(NOTEBOOKS)]
    env = {
        **os.environ,
        "MARLANDER_BUDGET": "small",
        "MARLANDER_DOCS_EXECUTE": "false",
        "MARLANDER_DOCS_NOTEBOOKS": str(copies[0].parent),
    }
    build = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT_S,
    )
    assert build.returncode == 0, f"mkdocs build failed:\n{build.stdout[-3000:]}\n{build.stderr[-6000:]}"

    pages = {nb_path.stem: site / "notebooks" / nb_path.stem / "index.html" for nb_path in NOTEBOOKS}
    assert all(page.is_file() for page in pages.values()), "a notebook has no page"
    for name in ("index", "paper_to_code/index", "reproduction/index", "lab_guide/index", "references/index"):
        assert (site / f"{name}.html").is_file(), f"{name}.html is missing"
    assert "marlander_lite" in (site / "index.html").read_text(encoding="utf-8")  # the README is the home page

    assert broken_links(site) == []

    chromium = find_chromium()
    if chromium is None:
        pytest.skip("chromium is not installed (apt-get install chromium): the figure check needs a browser")
    plotting = plotting_notebooks()
    assert plotting, "no notebook plots anything: the figure check would prove nothing"
    rendered = {name: rendered_images(chromium, page) for name, page in pages.items()}
    missing = [f"{name}: {rendered[name]}" for name in plotting if rendered[name]["decoded"] == 0]
    undecoded = [f"{name}: {r}" for name, r in rendered.items() if r["decoded"] < r["images"]]
    assert not missing, f"notebook pages without a rendered figure: {missing}"
    assert not undecoded, f"images the browser could not decode: {undecoded}"
