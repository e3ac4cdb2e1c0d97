"""Markdown tables and the generated blocks of the docs pages."""
from __future__ import annotations

import math
from pathlib import Path


def cell(value, digits: int = 2) -> str:
    """A number to ``digits`` decimals, "—" for None/NaN; strings as they are."""
    if isinstance(value, str):
        return value
    if isinstance(value, (int,)) and not isinstance(value, bool):
        return str(value)
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.{digits}f}"


def markdown(header: list[str], rows: list[list], align: str | None = None) -> str:
    """A markdown table; ``align`` one letter a column (l/r), default: first left, rest right."""
    align = align or "l" + "r" * (len(header) - 1)
    rule = "|" + "|".join("---" if a == "l" else "---:" for a in align) + "|"
    lines = ["| " + " | ".join(header) + " |", rule]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def block(page_text: str, key: str, text: str) -> str:
    """``page_text`` with the text between ``<!-- key:start -->`` and ``<!-- key:end -->``
    replaced by ``text`` (the markers appended when the page lacks them)."""
    start, end = f"<!-- {key}:start -->", f"<!-- {key}:end -->"
    new = f"{start}\n{text.rstrip()}\n{end}"
    if start in page_text and end in page_text:
        return page_text[:page_text.index(start)] + new + page_text[page_text.index(end) + len(end):]
    return page_text.rstrip("\n") + "\n\n" + new + "\n"


def write_block(path: Path, key: str, text: str, title: str | None = None) -> None:
    """Replace the ``key`` block of the page at ``path`` (a new page gets ``title``)."""
    path = Path(path)
    page = path.read_text() if path.is_file() else (f"# {title}\n\n" if title else "")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(block(page, key, text) if page else block("", key, text).lstrip("\n"))
