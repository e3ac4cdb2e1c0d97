"""The rows of ``cases.csv``: their columns, reading/writing them, and grouping them for tables.

Pure data helpers shared by the runner, the report and the plots (no Lightning, no matplotlib), so
that ``report`` and ``plots`` both import from here and not from each other.
"""
from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

#: Metrics of ``torchfill.metrics.score`` written for every case.
SCORE_METRICS = ["rmse", "ave", "std", "rmse_missing", "gap_error"]
#: Columns after the case key: the solver, its scores and its diagnostics (observed data only).
TAIL = ["solver", *SCORE_METRICS, "n_iter", "rank", "converged", "stop", "solve_s", "wall_s", "T",
        "J", "status"]
#: Solver attributes that hold the rank it settled on, in the order they are looked up.
RANK_ATTRIBUTES = ("rank_", "chosen_rank_", "rank_chosen_")


def columns(grid_keys) -> list[str]:
    """The header of ``cases.csv`` for a config whose grid (and segment) keys are ``grid_keys``."""
    return ["recording", *grid_keys, "seed", "method", *TAIL]


def key_row(case) -> dict[str, Any]:
    """The identifying columns of ``case``."""
    return {"recording": case.recording, **dict(case.point), "seed": case.seed,
            "method": case.method.label}


def row_key(row: dict, grid_keys) -> tuple[str, ...]:
    """The key of a CSV row, comparable with :attr:`~torchfill.lightning.config.Case.key`."""
    return (row["recording"], *(str(row[k]) for k in grid_keys), str(row["seed"]), row["method"])


def solver_rank(solver) -> str:
    """The rank the solver settled on (e.g. Tucker's chosen multilinear rank), as text; ''."""
    for name in RANK_ATTRIBUTES:
        value = getattr(solver, name, None)
        if value is not None:
            value = value.tolist() if hasattr(value, "tolist") else value
            return "x".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)
    return ""


def ok(rows: list[dict]) -> list[dict]:
    """The finished rows."""
    return [r for r in rows if r.get("status") == "ok"]


def num(text) -> float:
    """A CSV cell as a float (NaN when empty or not a number)."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return float("nan")


def sort_key(value: str):
    """Numbers in numeric order, then text."""
    try:
        return (0, float(value), "")
    except (TypeError, ValueError):
        return (1, 0.0, str(value))


def summarize(rows: list[dict], by: list[str], column: str, metric: str) -> dict:
    """``{row key: {column value: array of metric values}}`` over the finished rows."""
    cells: dict = defaultdict(lambda: defaultdict(list))
    for r in ok(rows):
        cells[tuple(r[k] for k in by)][r[column]].append(num(r[metric]))
    return {k: {c: np.array(v) for c, v in cols.items()} for k, cols in cells.items()}


def mean_std(values: np.ndarray) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1; 0 for a single value)."""
    return float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


def read_rows(path: Path) -> list[dict]:
    """Every complete row of a ``cases.csv`` (a torn last line is dropped)."""
    if not Path(path).exists():
        return []
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        n = len(reader.fieldnames or [])
        return [r for r in reader if None not in r and None not in r.values() and len(r) == n]


def read_header(path: Path) -> list[str] | None:
    with open(path, newline="") as handle:
        return next(csv.reader(handle), None)


def rewrite(path: Path, header: list[str], rows: list[dict]) -> None:
    """Write ``rows`` under ``header`` atomically (missing cells empty)."""
    from ..io.outputs import Outputs

    def serialise(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=header, restval="", extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
    with Outputs() as out:
        out.write(path, serialise, "result file")
