"""Quality control of a fill on real gaps: which filled gaps to trust (``torchfill qc``).

For every gap of every marker in the input: its frames, whether it was interpolated (observed on
both sides) or extrapolated (touching a trial end), whether rigid donors (>= 3 rigid partners
observed) were available, the largest deviation from the rigid partners' observed distances, the
velocity jump at its edges, its largest one-frame step against the recording's teleport limit,
its samples outside the observed volume and those left unfilled; then a one-line verdict,
``ok`` or ``check`` with the reasons. The HTML report adds plots of the worst gaps (observed,
filled and partner distance), embedded, so the page is self-contained.

Thresholds, all from the recording's own observed samples (no units): teleport = a step longer
than 1.5 x the 99.9th-percentile observed step; edge jump = a velocity change larger than 1.5 x
the 99.9th-percentile observed one (frame-to-frame change of a step); rigid deviation = more than
3 x the rigid tolerance (``tol x scale``, about 9 mm on an adult body); long = more than
``LONG_SECONDS``.
"""
from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass

import numpy as np

from . import metrics
from .solvers.rigid import rigid_fill, rigid_pairs

#: Gaps longer than this many seconds are flagged ``long``.
LONG_SECONDS = 2.0


@dataclass
class Limits:
    step: float
    accel: float
    rigid: float
    bounds: tuple


def limits(points, observed, pairs) -> Limits:
    """Teleport, edge-jump, rigid-deviation and volume thresholds of a recording."""
    X = np.asarray(points, dtype=np.float64)
    both = observed[2:] & observed[1:-1] & observed[:-2]
    acc = np.linalg.norm(X[2:] - 2 * X[1:-1] + X[:-2], axis=2)[both]
    return Limits(step=metrics.step_limit(X, observed),
                  accel=1.5 * float(np.percentile(acc, 99.9)) if acc.size else np.inf,
                  rigid=3 * 0.005 * pairs.scale, bounds=metrics.volume(X, observed))


def gap_table(points, filled, rate: float | None = None, names=None, std=None) -> list[dict]:
    """One row per gap of ``points`` (the input), judged on ``filled`` (the fill's output).
    ``std`` (T, J), optional: the fill's estimated error std (``fill(..., return_std=True)``); each
    row then has its RMS over the gap as ``est_std``."""
    X = np.asarray(points, dtype=np.float64)
    F = np.asarray(filled, dtype=np.float64)
    missing = ~np.isfinite(X).all(axis=2)
    observed = ~missing
    T = X.shape[0]
    pairs = rigid_pairs(np.where(observed[..., None], X, np.nan), observed)
    _, donors = rigid_fill(X, observed, pairs, "auto" if names is not None else "data", names)
    donors = donors.numpy()
    lim = limits(X, observed, pairs)
    rigid = pairs.matrix(pairs.rigid & ~pairs.duplicate, fill=False).astype(bool)
    ref = pairs.matrix(pairs.distance)
    black = ~observed.any(axis=1)
    rows = []
    for j, a, b in metrics.gap_runs(missing):
        if not observed[:, j].any():
            continue
        rows.append(_gap_row(X, F, j, a, b, T, rate, names, donors, lim, rigid, ref, black))
        if std is not None:
            s = np.asarray(std, dtype=np.float64)[a:b, j]
            rows[-1]["est_std"] = float(np.sqrt(np.mean(s[np.isfinite(s)] ** 2))) \
                if np.isfinite(s).any() else np.nan
    return rows


def _gap_row(X, F, j, a, b, T, rate, names, donors, lim, rigid, ref, black) -> dict:
    seg = F[max(a - 1, 0):min(b + 1, T), j]
    steps = np.linalg.norm(np.diff(seg, axis=0), axis=1)
    partners = np.flatnonzero(rigid[j])
    dev = np.abs(np.linalg.norm(F[a:b, j][:, None] - F[a:b][:, partners], axis=2) - ref[j, partners])
    gap_mask = np.zeros(X.shape[:2], dtype=bool)
    gap_mask[a:b, j] = True
    jumps = metrics.edge_jumps(F, gap_mask)
    inside = np.isfinite(F[a:b, j]).all(axis=1)
    row = {
        "marker": names[j] if names is not None else str(j), "j": int(j),
        "start": int(a), "stop": int(b), "frames": int(b - a),
        "seconds": (b - a) / rate if rate else np.nan,
        "kind": "extrapolated" if a == 0 or b == T else "interpolated",
        "rigid_donors": float(donors[a:b, j].mean()),
        "rigid_dev": float(np.nanmax(dev)) if dev.size and np.isfinite(dev).any() else np.nan,
        "edge_jump": float(jumps.max()) if jumps.size else np.nan,
        "max_step": float(np.nanmax(steps)) if np.isfinite(steps).any() else np.nan,
        "outside": metrics.outside_volume(F[a:b, j][:, None], np.ones((b - a, 1), bool), lim.bounds),
        "unfilled": int((~inside).sum()), "blackout": int(black[a:b].sum()),
        "step_limit": lim.step,
    }
    row["verdict"] = _verdict(row, lim)
    return row


def _verdict(row: dict, lim: Limits) -> str:
    why = []
    if row["kind"] == "extrapolated" and row["rigid_donors"] < 1:
        why.append("extrapolated")
    if row["max_step"] > lim.step:
        why.append("teleport")
    if row["edge_jump"] > lim.accel:
        why.append("edge jump")
    if row["rigid_dev"] > lim.rigid:
        why.append("rigid deviation")
    if row["outside"]:
        why.append("outside volume")
    if row["unfilled"]:
        why.append("unfilled")
    if row["blackout"]:
        why.append("blackout")
    if row["seconds"] > LONG_SECONDS and row["rigid_donors"] < 1:
        why.append("long, no donors")
    return "ok" if not why else "check: " + ", ".join(why)


def format_table(rows: list[dict], units: str = "") -> str:
    """The gap table as fixed-width text."""
    head = (f"{'marker':<16}{'frames':>14}{'len':>6}  {'kind':<13}{'donors':>7}{'rigid_dev':>10}"
            f"{'edge_jump':>10}{'max_step':>10}{'outside':>8}{'unfilled':>9}  verdict")
    lines = [f"units {units}; max_step limit {rows[0]['step_limit']:.4g}" if rows else "no gaps", head]
    for r in rows:
        lines.append(f"{r['marker'][:15]:<16}{r['start']:>7}-{r['stop'] - 1:<6}{r['frames']:>6}  "
                     f"{r['kind']:<13}{r['rigid_donors']:>7.0%}{r['rigid_dev']:>10.3g}"
                     f"{r['edge_jump']:>10.3g}{r['max_step']:>10.3g}{r['outside']:>8d}"
                     f"{r['unfilled']:>9d}  {r['verdict']}")
    return "\n".join(lines)


def _worst(rows: list[dict], n: int) -> list[dict]:
    def badness(r):
        return (r["verdict"] != "ok", r["verdict"].count(",") + 1, r["frames"])
    return sorted(rows, key=badness, reverse=True)[:n]


def _plot(X, F, row, rigid, ref, labels, rate) -> str:
    """One gap as an embedded PNG: coordinates (observed, filled) and partner distances."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = X.shape[0]
    j, a, b = row["j"], row["start"], row["stop"]
    pad = max(20, (b - a) // 2)
    lo, hi = max(0, a - pad), min(T, b + pad)
    t = np.arange(lo, hi) / (rate or 1.0)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.2))
    for c, name in enumerate("xyz"):
        axes[0].plot(t, F[lo:hi, j, c], "--", lw=1, color=f"C{c}")
        axes[0].plot(t, X[lo:hi, j, c], "-", lw=2, color=f"C{c}", label=name)
    for ax in axes:
        ax.axvspan(a / (rate or 1.0), (b - 1) / (rate or 1.0), color="0.9")
        ax.set_xlabel("s" if rate else "frame")
    axes[0].set_title(f"{row['marker']} frames {a}-{b - 1}: observed (solid), filled (dashed)",
                      fontsize=9)
    axes[0].legend(fontsize=8)
    for k in np.flatnonzero(rigid[j])[:4]:
        d = np.linalg.norm(F[lo:hi, j] - F[lo:hi, k], axis=1)
        axes[1].plot(t, d - ref[j, k], lw=1, label=labels[k])
    axes[1].set_title("distance to rigid partners minus observed median", fontsize=9)
    if np.flatnonzero(rigid[j]).size:
        axes[1].legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def html_report(points, filled, rows: list[dict], *, title: str, rate=None, units="",
                names=None, n_plots: int = 6) -> str:
    """A self-contained HTML page: summary, the gap table (check rows first), worst-gap plots."""
    X, F = np.asarray(points, dtype=np.float64), np.asarray(filled, dtype=np.float64)
    observed = np.isfinite(X).all(axis=2)
    pairs = rigid_pairs(X)
    rigid = pairs.matrix(pairs.rigid & ~pairs.duplicate, fill=False).astype(bool)
    labels = names or [str(j) for j in range(X.shape[1])]
    n_check = sum(r["verdict"] != "ok" for r in rows)
    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(title)}</title>",
             "<style>body{font-family:sans-serif;margin:20px}table{border-collapse:collapse;"
             "font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
             "td.l{text-align:left}tr.check{background:#fff1e0}</style></head><body>",
             f"<h1>torchfill qc: {esc(title)}</h1>",
             f"<p>{X.shape[0]} frames, {X.shape[1]} markers, rate {rate or 'unknown'} Hz, "
             f"units {esc(units)}; {len(rows)} gaps, <b>{n_check} to check</b>; "
             f"{int((~observed.any(axis=1)).sum())} frames with no marker observed; "
             f"teleport limit {rows[0]['step_limit']:.4g} {esc(units)} per frame.</p>"
             if rows else "<p>no gaps</p>"]
    for row in _worst(rows, n_plots):
        png = _plot(X, F, row, rigid, pairs.matrix(pairs.distance), labels, rate)
        parts.append(f"<h3>{esc(row['marker'])} {row['start']}-{row['stop'] - 1}: "
                     f"{esc(row['verdict'])}</h3><img src='data:image/png;base64,{png}'>")
    cols = ["frames", "kind", "rigid_donors", "rigid_dev", "edge_jump", "max_step", "outside",
            "unfilled", *(["est_std"] if rows and "est_std" in rows[0] else []), "verdict"]
    parts.append("<h2>All gaps</h2><table><tr><th>marker</th><th>start-stop</th>"
                 + "".join(f"<th>{c}</th>" for c in cols) + "</tr>")
    for r in sorted(rows, key=lambda r: (r["verdict"] == "ok", r["j"], r["start"])):
        cells = "".join(f"<td class='l'>{esc(str(r[c]))}</td>" if isinstance(r[c], str)
                        else f"<td>{r[c]:.3g}</td>" for c in cols)
        cls = "" if r["verdict"] == "ok" else " class='check'"
        parts.append(f"<tr{cls}><td class='l'>{esc(r['marker'])}</td>"
                     f"<td>{r['start']}-{r['stop'] - 1}</td>{cells}</tr>")
    parts.append("</table></body></html>")
    return "\n".join(parts)
