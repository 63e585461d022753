"""MkDocs hooks that build the documentation site from files that live outside ``docs/``.

``mkdocs.yml`` loads this file (``hooks:``). It keeps one home per concept: the README, the
notebooks and the result figures stay where they are in the repository, and the site reads them
from there instead of from copies under ``docs/``.

* ``docs/index.md`` holds the line ``<!-- site-include: README.md -->``, replaced by the README.
* every ``notebooks/*.ipynb`` becomes the page ``notebooks/<name>/``, listed in the nav's
  ``Notebooks`` section; mkdocs-jupyter renders it
  (and executes it, with the budget of ``MARLANDER_BUDGET``), because this hook runs before it.
  With ``MARLANDER_DOCS_NOTEBOOKS=<folder>`` the pages come from that folder's copies of the notebooks
  instead (a folder named ``notebooks``, already executed, e.g. by the test suite; build them with
  ``MARLANDER_DOCS_EXECUTE=false``), so that a notebook is never run twice.
* the figures under ``data/results/`` become site files, and the pages' links to them
  (``../data/results/...`` from ``docs/``) are rewritten to point at those copies.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
INCLUDE = re.compile(r"^<!-- site-include: (?P<path>[\w./-]+) -->$", re.MULTILINE)
FIGURE_SUFFIXES = (".png", ".svg", ".jpg")


def _add(files: Files, config, path: Path, root: Path = ROOT) -> None:
    # A File rooted at the repository (not File.generated: mkdocs-jupyter's wrapper recomputes
    # abs_src_path from src_dir, which a generated file does not have).
    src_uri = path.relative_to(root).as_posix()
    if files.get_file_from_path(src_uri) is None:
        files.append(File(src_uri, str(root), config["site_dir"], config["use_directory_urls"]))


def executed_copies() -> list[Path] | None:
    """The copies named by ``MARLANDER_DOCS_NOTEBOOKS`` (one per notebook of the repository), or ``None``."""
    folder = os.environ.get("MARLANDER_DOCS_NOTEBOOKS")
    if not folder:
        return None
    if Path(folder).name != "notebooks":
        raise ValueError(
            f"MARLANDER_DOCS_NOTEBOOKS={folder}: the folder must be named 'notebooks', so that its pages keep the "
            "URLs notebooks/<name>/ that the docs link to"
        )
    copies = [Path(folder) / path.name for path in notebooks()]
    missing = [path.name for path in copies if not path.is_file()]
    if missing:
        raise FileNotFoundError(
            f"MARLANDER_DOCS_NOTEBOOKS={folder} lacks {missing}: it must hold an executed copy of every notebook "
            "under notebooks/ (or unset it to render the repository's notebooks)"
        )
    return copies


def notebooks() -> list[Path]:
    """Every notebook of the repository, in the order of their numbers."""
    return sorted((ROOT / "notebooks").glob("*.ipynb"))


def on_config(config):
    """Fill the nav's empty ``Notebooks`` section with every notebook, so that a new one is never left out."""
    for entry in config["nav"] or []:
        if isinstance(entry, dict) and entry.get("Notebooks") == []:
            entry["Notebooks"] = [f"notebooks/{path.name}" for path in notebooks()]
    return config


@event_priority(100)  # before mkdocs-jupyter turns the notebooks into pages
def on_files(files: Files, config) -> Files:
    copies = executed_copies()
    for notebook in copies or notebooks():
        # A copy is added as notebooks/<name> of its folder's parent: the same page URL as the repository's notebook.
        _add(files, config, notebook, root=notebook.parents[1] if copies else ROOT)
    for figure in sorted((ROOT / "data" / "results").rglob("*")):
        if figure.suffix in FIGURE_SUFFIXES:
            _add(files, config, figure)
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    def include(match: re.Match) -> str:
        return (ROOT / match["path"]).read_text(encoding="utf-8")

    markdown = INCLUDE.sub(include, markdown)
    # Pages under docs/ link to ../data/...; in the site the figures sit at the site root's data/.
    depth = page.file.src_uri.count("/")
    return markdown.replace("](../data/", "](" + "../" * depth + "data/")
