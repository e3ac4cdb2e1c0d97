"""Result rows: one CSV per suite run, one row per (case, method) or whatever keys the suite
names, written as each row finishes; a rerun skips the rows already there (resumable)."""
from __future__ import annotations

import csv
import os
from pathlib import Path


def read_csv(path: Path) -> list[dict]:
    """The rows of ``path`` (strings; numbers through :func:`num`), [] when absent."""
    path = Path(path)
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows (keys in order of first appearance) to ``path`` atomically, floats to 6 digits."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=keys, lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, path)


def num(value, default: float = float("nan")) -> float:
    """A CSV cell as a float (empty or unparsable: ``default``)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return default


class Rows:
    """The rows of one run, kept in ``path`` (None: in memory only). ``done(**key)`` says whether
    a row with those key values is there; ``add(row)`` appends and rewrites the file."""

    def __init__(self, path: Path | None, keys: tuple[str, ...]):
        self.path, self.keys = (Path(path) if path else None), keys
        self.rows = read_csv(self.path) if self.path else []

    def _key(self, row: dict) -> tuple:
        return tuple(str(row.get(k, "")) for k in self.keys)

    def done(self, **key) -> bool:
        want = self._key(key)
        return any(self._key(r) == want for r in self.rows)

    def get(self, **key) -> dict | None:
        want = self._key(key)
        return next((r for r in self.rows if self._key(r) == want), None)

    def add(self, row: dict) -> None:
        self.rows = [r for r in self.rows if self._key(r) != self._key(row)] + [row]
        if self.path:
            write_csv(self.path, self.rows)
