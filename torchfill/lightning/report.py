"""Results of an experiment, from the rows of ``cases.csv``: ``table.md`` in the papers' layout
(mean ± std over seeds, best value per row in bold, a mean row, published reference columns), the
solvers' diagnostics (iterations, chosen rank), a worst/median-seed stability check, and the PNG
plots."""
from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from .config import Config
from .rows import mean_std, num, ok, sort_key, summarize

LABELS = {"rmse": "RMSE", "ave": "AvE", "std": "STD", "rmse_missing": "RMSE (missing entries)",
          "gap_error": "mean 3-D gap error"}


def _reference_cells(references: dict, by: list[str], metric: str) -> dict[str, dict[tuple, float]]:
    """``{label: {row key: value}}`` of the published numbers for ``metric``."""
    out = {}
    for label, entries in (references or {}).items():
        cells = {tuple(e[k] for k in by): e[metric] for e in entries if metric in e}
        if cells:
            out[label] = cells
    return out


def _match(key: tuple, cells: dict) -> float | None:
    """A reference value for a table row; recordings match with or without their extension."""
    def strip(k: tuple) -> tuple:
        return tuple(Path(v).stem if v.endswith((".c3d", ".trc")) else v for v in k)

    return next((v for k, v in cells.items() if strip(k) == strip(key)), None)


def table_markdown(rows: list[dict], by: list[str], column: str, metric: str,
                   columns: list[str], digits: int = 2, references: dict | None = None,
                   mean_row: bool = True) -> str:
    """One markdown table: a line per ``by`` key, a column per published reference then per
    ``columns`` value, the cells ``mean ± std`` of ``metric`` over seeds (``(n=k)`` where a cell
    has fewer values than the fullest one: an unfinished grid); the lowest mean of each line in
    bold (every metric here is an error, lower is better). With ``mean_row``, a last line holds
    each column's mean over the lines where every column has a value."""
    cells = summarize(rows, by, column, metric)
    refs = {label: ref for label, ref in _reference_cells(references, by, metric).items()
            if any(_match(k, ref) is not None for k in cells)}
    present = [c for c in columns if any(c in v for v in cells.values())]
    lines = ["| " + " | ".join(by + list(refs) + present) + " |",
             "|" + "---|" * (len(by) + len(refs) + len(present))]
    keys = sorted(cells, key=lambda k: tuple(sort_key(v) for v in k))
    full_n = max((len(v) for cols in cells.values() for v in cols.values()), default=0)
    for key in keys:
        stats = {c: mean_std(v) for c, v in cells[key].items()}
        best = min((m for m, _ in stats.values()), default=None)
        out = []
        for label in refs:
            value = _match(key, refs[label])
            out.append("–" if value is None else f"{value:.{digits}f}")
        for c in present:
            if c not in stats:
                out.append("–")
                continue
            m, s = stats[c]
            text = f"{m:.{digits}f} ± {s:.{digits}f}"
            text = f"**{text}**" if m == best else text
            n = len(cells[key][c])
            out.append(text + (f" (n={n})" if n < full_n else ""))   # an unfinished cell
        lines.append("| " + " | ".join(list(key) + out) + " |")
    full = [k for k in keys if all(c in cells[k] for c in present)]
    if mean_row and len(full) > 1:
        means = [float(np.mean([cells[k][c].mean() for k in full])) for c in present]
        best = min(means)
        text = [f"**{m:.{digits}f}**" if m == best else f"{m:.{digits}f}" for m in means]
        lines.append("| " + " | ".join([f"mean of {len(full)} rows"] + [""] * (len(by) - 1)
                                       + [""] * len(refs) + text) + " |")
    return "\n".join(lines)


def stability_markdown(rows: list[dict], by: list[str], metric: str, columns: list[str]) -> str:
    """Blow-up check: per method, the largest ratio over table lines of the worst seed's ``metric``
    to the median seed's (1 = every seed alike), and the line where it happens."""
    cells = summarize(rows, [*by], "method", metric)
    lines = ["| method | worst seed / median seed | at | seeds per line |", "|---|---|---|---|"]
    for c in columns:
        ratios = [(float(v[c].max() / max(np.median(v[c]), 1e-12)), k, len(v[c]))
                  for k, v in cells.items() if c in v and len(v[c]) > 1]
        if ratios:
            r, k, n = max(ratios)
            lines.append(f"| {c} | {r:.2f} | {' '.join(k)} | {n} |")
    return "\n".join(lines) if len(lines) > 2 else ""


def diagnostics_markdown(rows: list[dict], by: list[str], columns: list[str]) -> str:
    """The solvers' own diagnostics (observed data only) per line and method: mean iterations and,
    where the solver reports one, its most frequent chosen rank."""
    cells: dict = {}
    for r in ok(rows):
        cells.setdefault(tuple(r[k] for k in by), {}).setdefault(r["method"], []).append(r)
    present = [c for c in columns if any(c in v for v in cells.values())]
    if not any(num(r.get("n_iter")) > 1 for r in ok(rows)):
        return ""
    lines = ["| " + " | ".join(by + present) + " |", "|" + "---|" * (len(by) + len(present))]
    for key in sorted(cells, key=lambda k: tuple(sort_key(v) for v in k)):
        out = []
        for c in present:
            sel = cells[key].get(c, [])
            if not sel:
                out.append("–")
                continue
            text = f"{np.mean([num(r['n_iter']) for r in sel]):.0f}"
            ranks = [r.get("rank", "") for r in sel if r.get("rank")]
            if ranks:
                text += " / " + max(set(ranks), key=ranks.count)
            out.append(text)
        lines.append("| " + " | ".join(list(key) + out) + " |")
    return "\n".join(lines)


def timing_markdown(rows: list[dict], columns: list[str]) -> str:
    """Per method: cases, mean iterations, mean solver seconds and mean wall seconds per case."""
    lines = ["| method | cases | iterations | solver s | wall s (Lightning incl.) |",
             "|---|---|---|---|---|"]
    for c in columns:
        sel = [r for r in ok(rows) if r["method"] == c]
        if not sel:
            continue
        it = np.mean([num(r["n_iter"]) for r in sel])
        solve = np.mean([num(r["solve_s"]) for r in sel])
        wall = np.mean([num(r["wall_s"]) for r in sel])
        lines.append(f"| {c} | {len(sel)} | {it:.1f} | {solve:.3f} | {wall:.3f} |")
    return "\n".join(lines)


def _intro(cfg: Config, rows: list[dict], by: list[str], command: str, notes, skipped) -> list[str]:
    done, failed = ok(rows), [r for r in rows if r.get("status") != "ok"]
    seeds = sorted({int(r["seed"]) for r in done})
    parts = [f"# {cfg.name}", ""]
    if cfg.raw.get("description"):
        parts += [str(cfg.raw["description"]).strip(), ""]
    segments = (f", {cfg.segments[1]} test segments of {cfg.segments[0]} frames per recording"
                if cfg.segments else "")
    parts += [f"Regenerate: `{command}` — {_dt.date.today().isoformat()}.", "",
              f"Protocol `{cfg.protocol}`, grid {cfg.grid}{segments}, seeds {seeds}: {len(done)} "
              "finished cases" + (f", {len(failed)} failed" if failed else "") + ". "
              "Cells: mean ± std (ddof=1) over seeds"
              + (" and the other grid keys" if set(cfg.keys) - set(by) else "")
              + "; best (lowest) mean of each row in **bold**. Errors in the recordings' units "
              "(below), metrics as defined in `torchfill.metrics`.", ""]
    if cfg.references:
        parts += [f"Reference columns ({', '.join(cfg.references)}): published numbers from the "
                  "config's `references:`, not run here.", ""]
    if notes:
        parts += ["Recordings (only markers observed in every frame are used as truth):", ""]
        parts += [f"- {n}" for n in notes] + [""]
    if skipped:
        parts += [f"Methods listed but not registered (skipped): {', '.join(skipped)}.", ""]
    return parts


def write_report(cfg: Config, rows: list[dict], out_dir: Path, runs_dir: Path, *, notes=(),
                 skipped=(), command: str = "") -> None:
    """``table.md`` and the plots for ``rows`` into ``out_dir``."""
    from . import plots

    table = cfg.table
    by, column, main = table["rows"], table["columns"], table["metric"]
    metric_list = [main] + [m for m in cfg.metrics if m != main]
    order = [m.label for m in cfg.methods]
    digits = int(table.get("digits", 2))
    parts = _intro(cfg, rows, by, command, notes, skipped)
    columns = order if column == "method" else sorted({r[column] for r in ok(rows)}, key=sort_key)
    for metric in metric_list:
        parts += [f"## {LABELS.get(metric, metric)}", "",
                  table_markdown(rows, by, column, metric, columns, digits, cfg.references), ""]
    if column == "method":
        check = stability_markdown(rows, ["recording", *cfg.keys], main, order)
        if check:
            parts += ["## Stability over seeds", "", f"Largest ratio of the worst seed's {main} "
                      "to the median seed's over every setting (recording and grid point).", "",
                      check, ""]
        diag = diagnostics_markdown(rows, by, order)
        if diag:
            parts += ["## Solver diagnostics", "", "Mean iterations / most frequent chosen rank "
                      "(observed data only; iterative methods).", "", diag, ""]
    parts += ["## Time per case", "", timing_markdown(rows, order), ""]
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        parts += ["## Failed cases", ""]
        parts += [f"- {r['recording']} seed {r['seed']} {r['method']}: {r['status']}" for r in failed]
        parts += [""]
    images = plots.write_plots(cfg, rows, out_dir, runs_dir, order=order, metric=main)
    if images:
        parts += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in images] + [""]
    from ..io.outputs import Outputs

    with Outputs() as out:
        out.write_text(out_dir / "table.md", "\n".join(parts), "result file")
