"""Results of an experiment: ``table.md`` in the papers' layout (mean ± std over seeds, best value
per row in bold) and the PNG plots, from the rows of ``cases.csv``."""
from __future__ import annotations

import datetime as _dt
from collections import defaultdict
from pathlib import Path

import numpy as np

from .config import Config

LABELS = {"rmse": "RMSE", "ave": "AvE", "std": "STD", "rmse_missing": "RMSE (missing entries)",
          "gap_error": "mean 3-D gap error"}


def _ok(rows: list[dict]) -> list[dict]:
    return [r for r in rows if r.get("status") == "ok"]


def _num(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return float("nan")


def _sort_key(value: str):
    try:
        return (0, float(value), "")
    except ValueError:
        return (1, 0.0, value)


def summarize(rows: list[dict], by: list[str], column: str, metric: str) -> dict:
    """``{row key: {column value: array of metric values}}`` over the finished rows."""
    cells: dict = defaultdict(lambda: defaultdict(list))
    for r in _ok(rows):
        cells[tuple(r[k] for k in by)][r[column]].append(_num(r[metric]))
    return {k: {c: np.array(v) for c, v in cols.items()} for k, cols in cells.items()}


def mean_std(values: np.ndarray) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1; 0 for a single value)."""
    return float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


def table_markdown(rows: list[dict], by: list[str], column: str, metric: str,
                   columns: list[str], digits: int = 2) -> str:
    """One markdown table: a line per ``by`` key, a column per ``columns`` value, the cells
    ``mean ± std`` of ``metric``; the lowest mean of each line in bold (every metric here is an
    error, lower is better)."""
    cells = summarize(rows, by, column, metric)
    present = [c for c in columns if any(c in v for v in cells.values())]
    lines = ["| " + " | ".join(by + present) + " |", "|" + "---|" * (len(by) + len(present))]
    for key in sorted(cells, key=lambda k: tuple(_sort_key(v) for v in k)):
        stats = {c: mean_std(v) for c, v in cells[key].items()}
        best = min((m for m, _ in stats.values()), default=None)
        out = []
        for c in present:
            if c not in stats:
                out.append("–")
                continue
            m, s = stats[c]
            text = f"{m:.{digits}f} ± {s:.{digits}f}"
            out.append(f"**{text}**" if m == best else text)
        lines.append("| " + " | ".join(list(key) + out) + " |")
    return "\n".join(lines)


def timing_markdown(rows: list[dict], columns: list[str]) -> str:
    """Per method: cases, mean iterations, mean solver seconds and mean wall seconds per case."""
    lines = ["| method | cases | iterations | solver s | wall s (Lightning incl.) |",
             "|---|---|---|---|---|"]
    for c in columns:
        sel = [r for r in _ok(rows) if r["method"] == c]
        if not sel:
            continue
        it = np.mean([_num(r["n_iter"]) for r in sel])
        solve = np.mean([_num(r["solve_s"]) for r in sel])
        wall = np.mean([_num(r["wall_s"]) for r in sel])
        lines.append(f"| {c} | {len(sel)} | {it:.1f} | {solve:.3f} | {wall:.3f} |")
    return "\n".join(lines)


def write_report(cfg: Config, rows: list[dict], out_dir: Path, runs_dir: Path, *, notes=(),
                 skipped=(), command: str = "") -> None:
    """``table.md`` and the plots for ``rows`` into ``out_dir``."""
    from . import plots

    table = cfg.table
    by = table["rows"] if isinstance(table["rows"], list) else [table["rows"]]
    column = table.get("columns", "method")
    main = table["metric"]
    metric_list = [main] + [m for m in cfg.metrics if m != main]
    order = [m.label for m in cfg.methods]
    digits = int(table.get("digits", 2))
    ok = _ok(rows)
    seeds = sorted({int(r["seed"]) for r in ok})
    failed = [r for r in rows if r.get("status") != "ok"]
    parts = [f"# {cfg.name}", ""]
    if cfg.raw.get("description"):
        parts += [str(cfg.raw["description"]).strip(), ""]
    parts += [f"Regenerate: `{command}` — {_dt.date.today().isoformat()}.", "",
              f"Protocol `{cfg.protocol}`, grid {cfg.grid}, seeds {seeds}: {len(ok)} finished cases"
              + (f", {len(failed)} failed" if failed else "") + ". "
              "Cells: mean ± std (ddof=1) over seeds"
              + (" and the other grid keys" if set(cfg.grid) - set(by) else "")
              + "; best (lowest) mean of each row in **bold**. Errors in the recordings' units "
              "(below), metrics as defined in `torchfill.metrics`.", ""]
    if notes:
        parts += ["Recordings (only markers observed in every frame are used as truth):", ""]
        parts += [f"- {n}" for n in notes] + [""]
    if skipped:
        parts += [f"Methods listed but not registered (skipped): {', '.join(skipped)}.", ""]
    columns = order if column == "method" else sorted({r[column] for r in ok}, key=_sort_key)
    for metric in metric_list:
        parts += [f"## {LABELS.get(metric, metric)}", "",
                  table_markdown(rows, by, column, metric, columns, digits), ""]
    parts += ["## Time per case", "", timing_markdown(rows, order), ""]
    if failed:
        parts += ["## Failed cases", ""]
        parts += [f"- {r['recording']} seed {r['seed']} {r['method']}: {r['status']}" for r in failed]
        parts += [""]
    images = plots.write_plots(cfg, rows, out_dir, runs_dir, order=order, metric=main)
    if images:
        parts += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in images] + [""]
    (out_dir / "table.md").write_text("\n".join(parts))
