"""The one way the evaluation scripts put their generated tables into a docs page: the text between
``<!-- KEY:start -->`` and ``<!-- KEY:end -->`` is replaced (the markers are appended when the page
lacks them)."""
from __future__ import annotations

from pathlib import Path


def write_block(path: Path, key: str, text: str, title: str | None = None) -> None:
    """Replace the ``key`` block of the page at ``path`` with ``text`` (a new page gets ``title``)."""
    start, end = f"<!-- {key}:start -->", f"<!-- {key}:end -->"
    block = f"{start}\n{text.rstrip()}\n{end}"
    path = Path(path)
    if path.is_file():
        page = path.read_text()
        if start in page and end in page:
            page = page[:page.index(start)] + block + page[page.index(end) + len(end):]
        else:
            page = page.rstrip("\n") + "\n\n" + block + "\n"
    else:
        page = (f"# {title}\n\n" if title else "") + block + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page)
