"""The one way the evaluation scripts write their results: rows to a CSV (``write_csv``) and
generated tables into a docs page (``write_block``: the text between ``<!-- KEY:start -->`` and
``<!-- KEY:end -->`` is replaced; the markers are appended when the page lacks them)."""
from __future__ import annotations

import csv
from pathlib import Path


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows (dicts; keys in order of first appearance) to ``path``, floats to 6 digits."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=keys)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


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
