"""Generated blocks in Markdown documents: ``<!-- include: PATH -->`` ... ``<!-- end include -->``.

``docs/reproduction.md`` never holds a measured number typed by hand: each results table and
figure list is such a block, refreshed from the files ``marlander reproduce`` writes.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

_INCLUDE = re.compile(r"(<!-- include: (?P<path>\S+) -->\n)(?P<body>.*?)(<!-- end include -->)", re.DOTALL)
_LINK = re.compile(r"(!?\[[^\]]*\]\()(?P<target>[^)\s]+)(\))")


def update_includes(doc: Path) -> int:
    """Refresh every ``<!-- include: PATH -->`` ... ``<!-- end include -->`` block of ``doc``.

    ``PATH`` is relative to ``doc``'s folder; the block becomes that file's text, with relative
    links re-based so that images still resolve from ``doc``. A missing file leaves a note
    saying so. Returns the number of blocks refreshed.
    """
    text = doc.read_text()
    count = 0

    def replace(match: re.Match[str]) -> str:
        nonlocal count
        count += 1
        source = (doc.parent / match["path"]).resolve()
        if source.is_file():
            body = _rebase_links(source.read_text(), source.parent, doc.parent)
        else:
            body = f"_Not generated yet: `{match['path']}` does not exist (see the commands above)._\n"
        return match.group(1) + body.rstrip("\n") + "\n" + match.group(4)

    doc.write_text(_INCLUDE.sub(replace, text))
    return count


def _rebase_links(text: str, source_dir: Path, doc_dir: Path) -> str:
    def rebase(match: re.Match[str]) -> str:
        target = match["target"]
        if re.match(r"^([a-z]+:|#|/)", target):
            return match.group(0)
        new = os.path.relpath((source_dir / target).resolve(), doc_dir.resolve())
        return f"{match.group(1)}{Path(new).as_posix()}{match.group(3)}"

    return _LINK.sub(rebase, text)
