"""The QC verdicts as text (:func:`summary`, :func:`format_table`), JSON (:func:`to_json`) and one
self-contained HTML page (:func:`html_report`; no network: inline SVG, PNG and JavaScript):

- a summary with the thresholds in the file's units;
- a marker x time overview of every gap, coloured by verdict (frames numbered as in the file);
- a figure per gap that is not ``ok``: each coordinate observed around the gap, the fill with its
  +-2 sigma band (when the fill's std is known), and the distances to the rigid partners against
  their observed median +- spread;
- a table of every gap, sortable by clicking a column head, units in the heads.

The figures are inline SVG drawn here (no matplotlib: fast enough for hundreds of gaps, and a
label is HTML-escaped text, never parsed as mathtext).
"""
from __future__ import annotations

import html
import math
from dataclasses import asdict

import numpy as np

from ..solvers.rigid import rigid_pairs
from .verdicts import VERDICTS, rigid_partners, table_thresholds

#: Figures at most (the worst gaps first); the table lists every gap.
MAX_FIGURES = 200
#: Frames drawn at most per figure panel.
MAX_POINTS = 300
COLOURS = {"ok": "#4caf50", "check": "#ff9800", "reject": "#e53935"}
_ORDER = {"reject": 0, "check": 1, "ok": 2}


def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def summary(rows: list[dict], unfilled: int | None = None) -> str:
    """``N gaps: a ok, b check, c reject`` (+ unfilled). ``unfilled``: the missing samples the
    fill left NaN, markers never observed included (:func:`unfilled_samples`; the count
    ``torchfill fill`` gives); default: those of the gaps in ``rows``."""
    n = {v: sum(r["verdict"] == v for r in rows) for v in VERDICTS}
    empty = sum(r["filled_frames"] == 0 for r in rows)
    samples = sum(r["unfilled"] for r in rows) if unfilled is None else unfilled
    return (f"{len(rows)} gaps: {n['ok']} ok, {n['check']} check, {n['reject']} reject"
            + (f" ({empty} left unfilled)" if empty else "")
            + (f"; {samples} missing sample(s) left unfilled" if samples else ""))


def unfilled_samples(filled) -> int:
    """Samples NaN in the fill ``filled`` (T, J, D): the missing samples it left unfilled (observed
    ones are finite), counted as ``torchfill fill`` counts them."""
    return int((~np.isfinite(np.asarray(filled, dtype=np.float64)).all(axis=2)).sum())


def format_table(rows: list[dict], units: str = "", *, has_std: bool | None = None) -> str:
    """The gap table as fixed-width text, thresholds first (in the file's units)."""
    th = table_thresholds(rows)
    if th is None:
        return "no gaps"
    u = th.units or units
    has_std = any(np.isfinite(r["est_rmse"]) for r in rows) if has_std is None else has_std
    lines = [f"thresholds ({u}):"] + [f"  {line}" for line in th.lines()]
    if not has_std:
        lines.append("  no error estimate given: verdicts from the plausibility tests only "
                     "(fill --std OUT.csv, then qc --std OUT.csv)")
    width = max(6, min(16, max(len(r["marker"]) for r in rows)))
    rig = th.dims == 3                                  # no rigid bodies in image keypoints
    lines.append(f"{'marker':<{width}} {'frames':>13} {'len':>5} {'unfilled':>8} {'kind':<8} "
                 f"{'est_rmse':>9} {'max_step':>9} " + (f"{'rigid_x':>7} " if rig else "")
                 + f"{'support':>7}  verdict  reasons")
    lines.append(f"{'':<{width}} {'(file)':>13} {'':>5} {'(frames)':>8} {'':<8} "
                 f"{'(' + u + ')':>9} {'(' + u + ')':>9}" + (f" {'spread':>7}" if rig else ""))
    for r in rows:
        lines.append(f"{r['marker'][:width]:<{width}} {r['first_frame']:>6}-{r['last_frame']:<6} "
                     f"{r['frames']:>5} {r['unfilled']:>8} {r['kind']:<8} {r['est_rmse']:>9.3g} "
                     f"{r['max_step']:>9.3g} "
                     + (f"{r['rigid_ratio']:>7.3g} " if rig else "")
                     + f"{r['support']:>7.0%}  {r['verdict']:<7}  {'; '.join(r['reasons'])}")
    return "\n".join(lines)


def to_json(rows: list[dict]) -> list[dict]:
    """One JSON-ready object per gap: ``marker``, ``first_frame``, ``last_frame`` (the file's
    numbering), ``verdict``, ``est_rmse`` (file units, None without std), ``reasons``,
    ``segment`` (None until segments are known), plus the measurements."""
    out = []
    for r in rows:
        def num(v):
            return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v
        out.append({"marker": r["marker"], "first_frame": int(r["first_frame"]),
                    "last_frame": int(r["last_frame"]), "verdict": r["verdict"],
                    "est_rmse": num(r["est_rmse"]), "reasons": list(r["reasons"]),
                    "segment": r.get("segment"), "frames": r["frames"], "kind": r["kind"],
                    "filled_frames": r["filled_frames"], "unfilled": r["unfilled"],
                    "support": num(r["support"]),
                    "max_step": num(r["max_step"]), "rigid_ratio": num(r["rigid_ratio"]),
                    "rigid_partner": r["rigid_partner"] or None,
                    "at_volume_bound": r["at_volume_bound"],
                    "extrapolated": r["extrapolated"], "blackout": r["blackout"]})
    return out


def thresholds_json(rows: list[dict]) -> dict | None:
    th = table_thresholds(rows)
    if th is None:
        return None
    d = asdict(th)
    d["volume"] = [list(map(float, th.volume[0])), list(map(float, th.volume[1]))]
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def overview_svg(rows: list[dict], n_frames: int, labels, first_frame: int = 0,
                 width: int = 1000, filled=None) -> str:
    """Marker x time: one band per marker with gaps, a box per gap in its verdict's colour (the
    frames left unfilled greyed)."""
    js = sorted({r["j"] for r in rows})
    if not js:
        return ""
    row_h, left, top = 14, 150, 18
    plot_w = width - left - 10
    height = top + row_h * len(js) + 22
    x = lambda t: left + plot_w * t / max(n_frames, 1)       # noqa: E731
    esc = html.escape
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' "
           f"font-family='sans-serif' font-size='10' role='img'>"]
    for i, j in enumerate(js):
        y = top + i * row_h
        if i % 2:
            out.append(f"<rect x='{left}' y='{y}' width='{plot_w}' height='{row_h}' fill='#f4f4f4'/>")
        out.append(f"<text x='{left - 4}' y='{y + row_h - 3}' text-anchor='end'>"
                   f"{esc(str(labels[j]))[:24]}</text>")
    for r in rows:
        y = top + js.index(r["j"]) * row_h + 1
        x0, x1 = x(r["start"]), x(r["stop"])
        tip = (f"{r['marker']} frames {r['first_frame']}-{r['last_frame']}: {r['verdict']}"
               + (" (" + "; ".join(r["reasons"]) + ")" if r["reasons"] else ""))
        colour = COLOURS[r["verdict"]] if r["filled_frames"] else "#9e9e9e"
        out.append(f"<rect x='{x0:.1f}' y='{y}' width='{max(x1 - x0, 1.5):.1f}' "
                   f"height='{row_h - 2}' fill='{colour}'><title>{esc(tip)}</title></rect>")
        if filled is not None and 0 < r["unfilled"] < r["frames"]:
            hole = ~np.asarray(filled[r["start"]:r["stop"], r["j"]], dtype=bool)
            edges = np.flatnonzero(np.diff(np.r_[0, hole.astype(np.int8), 0]))
            for a, b in zip(edges[::2], edges[1::2]):
                xa, xb = x(r["start"] + a), x(r["start"] + b)
                out.append(f"<rect x='{xa:.1f}' y='{y}' width='{max(xb - xa, 1.5):.1f}' "
                           f"height='{row_h - 2}' fill='#9e9e9e'><title>{esc(tip)}: "
                           f"{b - a} frame(s) left unfilled</title></rect>")
    ticks = np.unique(np.linspace(0, n_frames - 1, 9).round().astype(int)) if n_frames > 1 else [0]
    base = top + row_h * len(js)
    out.append(f"<line x1='{left}' x2='{left + plot_w}' y1='{base}' y2='{base}' stroke='#555'/>")
    for t in ticks:
        out.append(f"<line x1='{x(t):.1f}' x2='{x(t):.1f}' y1='{base}' y2='{base + 4}' "
                   f"stroke='#555'/><text x='{x(t):.1f}' y='{base + 15}' text-anchor='middle'>"
                   f"{first_frame + t}</text>")
    out.append(f"<text x='{left - 20}' y='{base + 15}' text-anchor='end'>frame</text></svg>")
    return "".join(out)


def _ticks(lo: float, hi: float, n: int = 4) -> np.ndarray:
    """About ``n`` round tick values within [lo, hi]."""
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if np.isfinite(lo) else np.zeros(0)
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    return np.arange(math.ceil(lo / step) * step, hi + 1e-9 * step, step)


def _panel(t, series, *, title: str, gap, bands=(), w: int = 250, h: int = 150) -> str:
    """One small SVG chart: ``series`` = [(y, colour, dashed)], ``bands`` = [(lo, hi, colour)]
    (arrays over ``t``, NaN breaks a line), the gap's frames ``gap`` = (first, last) shaded."""
    L, R, T, B = 44, 6, 16, 22
    ys = [y for y, _, _ in series] + [v for lo, hi, _ in bands for v in (lo, hi)]
    finite = np.concatenate([np.asarray(y)[np.isfinite(y)] for y in ys] or [np.zeros(0)])
    y0, y1 = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if y1 - y0 < 1e-12:
        y0, y1 = y0 - 1.0, y1 + 1.0
    pad = 0.05 * (y1 - y0)
    y0, y1 = y0 - pad, y1 + pad
    t0, t1 = float(t[0]), float(max(t[-1], t[0] + 1))
    X = lambda v: L + (w - L - R) * (np.asarray(v, float) - t0) / (t1 - t0)      # noqa: E731
    Y = lambda v: T + (h - T - B) * (y1 - np.asarray(v, float)) / (y1 - y0)      # noqa: E731
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' "
           f"font-family='sans-serif' font-size='9'>",
           f"<text x='{w / 2:.0f}' y='11' text-anchor='middle' font-size='10'>"
           f"{html.escape(title)}</text>",
           f"<rect x='{X(gap[0] - 0.5):.1f}' y='{T}' width='{X(gap[1] + 0.5) - X(gap[0] - 0.5):.1f}'"
           f" height='{h - T - B}' fill='#ececec'/>"]
    for lo, hi, colour in bands:
        ok = np.isfinite(lo) & np.isfinite(hi)
        for a, b in _runs(ok):
            pts = [f"{X(t[k]):.1f},{Y(hi[k]):.1f}" for k in range(a, b)] + \
                  [f"{X(t[k]):.1f},{Y(lo[k]):.1f}" for k in range(b - 1, a - 1, -1)]
            out.append(f"<polygon points='{' '.join(pts)}' fill='{colour}' fill-opacity='0.25'/>")
    for y, colour, dashed in series:
        y = np.asarray(y, float)
        for a, b in _runs(np.isfinite(y)):
            pts = " ".join(f"{X(t[k]):.1f},{Y(y[k]):.1f}" for k in range(a, b))
            if b - a == 1:
                out.append(f"<circle cx='{X(t[a]):.1f}' cy='{Y(y[a]):.1f}' r='1.8' "
                           f"fill='{colour}'/>")
            else:
                out.append(f"<polyline points='{pts}' fill='none' stroke='{colour}' "
                           f"stroke-width='{1.4 if dashed else 1.8}'"
                           + (" stroke-dasharray='4 2'" if dashed else "") + "/>")
    out.append(f"<rect x='{L}' y='{T}' width='{w - L - R}' height='{h - T - B}' fill='none' "
               "stroke='#888'/>")
    for v in _ticks(y0, y1):
        out.append(f"<text x='{L - 3}' y='{Y(v) + 3:.1f}' text-anchor='end'>{v:.4g}</text>"
                   f"<line x1='{L - 2}' x2='{L}' y1='{Y(v):.1f}' y2='{Y(v):.1f}' stroke='#888'/>")
    for v in _ticks(t0, t1, 3):
        out.append(f"<text x='{X(v):.1f}' y='{h - B + 11}' text-anchor='middle'>{int(v)}</text>")
    out.append(f"<text x='{(L + w - R) / 2:.0f}' y='{h - 2}' text-anchor='middle'>frame</text>"
               "</svg>")
    return "".join(out)


def _runs(ok: np.ndarray):
    """(start, stop) of the runs of True in ``ok``."""
    edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(ok, dtype=np.int8), 0]))
    return zip(edges[::2], edges[1::2])


def gap_figure(X, F, std, row: dict, *, partners, labels, units: str,
               first_frame: int = 0) -> str:
    """One gap as inline SVG panels: each coordinate (observed black, the fill dashed blue with its
    +-2 sigma band when ``std`` is known) and the distances to up to 4 rigid partners minus their
    observed median (each with its +-spread band); ``partners`` = (k, median distance, spread)
    arrays (:func:`torchfill.qc.rigid_partners`), None: none."""
    T, _, D = X.shape
    j, a, b = row["j"], row["start"], row["stop"]
    pad = max(15, (b - a) // 2)
    lo, hi = max(0, a - pad), min(T, b + pad)
    # long windows drawn at most ~MAX_POINTS frames (every k-th, the gap's edges kept)
    idx = np.arange(lo, hi, max(1, -(-(hi - lo) // MAX_POINTS)))
    idx = np.unique(np.r_[idx, [f for f in (a - 1, a, b - 1, b) if lo <= f < hi]])
    t = first_frame + idx
    gap = (first_frame + a, first_frame + b - 1)
    X, F = X[idx], F[idx]
    lo, hi = 0, len(idx)
    seen = np.isfinite(X[:, j]).all(axis=1)
    # the fill joined to the observed samples next to it, so a one-frame gap shows as a line too
    near = np.convolve((~seen).astype(int), [1, 1, 1], "same") > 0
    s = None if std is None else np.asarray(std, dtype=np.float64)[idx, j]
    names = "xyz" if D == 3 else "xy" if D == 2 else [str(c) for c in range(D)]
    panels = []
    for c in range(D):
        obs = X[lo:hi, j, c]
        fill = np.where(~seen | near, F[lo:hi, j, c], np.nan)
        bands = []
        if s is not None and np.isfinite(s).any():
            f = np.where(~seen, F[lo:hi, j, c], np.nan)
            bands.append((f - 2 * s, f + 2 * s, "#1f77b4"))
        panels.append(_panel(t, [(fill, "#1f77b4", True), (obs, "#000", False)],
                             title=f"{names[c]} ({units})", gap=gap, bands=bands))
    legend = ["<span style='color:#000'>&#9473; observed</span>",
              "<span style='color:#1f77b4'>&#9476; fill</span>"
              + (" (band: &#177;2&#963;)" if s is not None and np.isfinite(s).any() else "")]
    if partners is not None and len(partners[0]):
        series, bands = [], []
        ks, ref, spread = partners
        for i, n in enumerate(np.argsort(spread, kind="stable")[:4]):   # most rigid first
            k, colour = ks[n], _PARTNER_COLOURS[i]
            d = np.linalg.norm(F[lo:hi, j] - F[lo:hi, k], axis=1) - ref[n]
            series.append((d, colour, False))
            bands.append((np.full(len(t), -spread[n]), np.full(len(t), spread[n]), colour))
            legend.append(f"<span style='color:{colour}'>&#9473; {html.escape(str(labels[k]))}"
                          "</span>")
        panels.append(_panel(t, series, title=f"partner distance - median ({units})", gap=gap,
                             bands=bands))
    return "".join(panels) + "<br><small>" + " &nbsp; ".join(legend) + "</small>"


_PARTNER_COLOURS = ("#ff7f0e", "#2ca02c", "#d62728", "#9467bd")


_SORT_JS = """
document.querySelectorAll('table.sortable th').forEach(function (th, col) {
  th.addEventListener('click', function () {
    var table = th.closest('table'), body = table.tBodies[0];
    var asc = th.getAttribute('data-dir') !== 'asc';
    table.querySelectorAll('th').forEach(function (h) { h.removeAttribute('data-dir'); });
    th.setAttribute('data-dir', asc ? 'asc' : 'desc');
    var rows = Array.prototype.slice.call(body.rows);
    rows.sort(function (a, b) {
      var x = a.cells[col].getAttribute('data-v'), y = b.cells[col].getAttribute('data-v');
      var nx = parseFloat(x), ny = parseFloat(y), r;
      if (!isNaN(nx) && !isNaN(ny)) r = nx - ny;
      else if (isNaN(nx) !== isNaN(ny)) r = isNaN(nx) ? 1 : -1;
      else r = x < y ? -1 : x > y ? 1 : 0;
      return asc ? r : -r;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  });
});
"""

_CSS = ("body{font-family:sans-serif;margin:20px;color:#222}table{border-collapse:collapse;"
        "font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
        "th{background:#eee;cursor:pointer;user-select:none}th[data-dir=asc]:after{content:' ▲'}"
        "th[data-dir=desc]:after{content:' ▼'}td.l,th.l{text-align:left}tr.check td.v{background:"
        "#ffe0b2}tr.reject td.v{background:#ffcdd2}tr.ok td.v{background:#dcedc8}"
        ".legend span{display:inline-block;width:12px;height:12px;margin:0 4px 0 12px;"
        "vertical-align:middle}figure{margin:14px 0;padding-left:8px;border-left:4px solid "
        "#ccc}figure.check{border-color:#ff9800}figure.reject{border-color:#e53935}"
        "figcaption{font-size:13px;margin-bottom:2px}svg{overflow:visible}")


def html_report(points, filled, rows: list[dict], *, title: str, rate=None, units="",
                names=None, std=None, first_frame: int = 0, max_figures: int = MAX_FIGURES) -> str:
    """The report page (see the module docstring) for the gap ``rows`` of :func:`qc.gap_table`."""
    X, F = np.asarray(points, dtype=np.float64), np.asarray(filled, dtype=np.float64)
    T, J, D = X.shape
    labels = list(names) if names is not None else [str(j) for j in range(J)]
    esc = html.escape
    u = esc(units or "")
    observed = np.isfinite(X).all(axis=2)
    partners_of = {}
    if D == 3 and observed.any():
        pairs = rigid_pairs(np.where(observed[..., None], X, np.nan), observed)
        partners_of = rigid_partners(pairs)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>torchfill qc: "
             f"{esc(title)}</title><style>{_CSS}</style></head><body>",
             f"<h1>torchfill qc: {esc(title)}</h1>"]
    f1 = first_frame + T - 1
    parts.append(f"<p>{T} frames (numbered {first_frame}-{f1} as in the file), {J} markers, rate "
                 f"{_fmt(rate) or 'unknown'} Hz, units {u}. <b>{esc(summary(rows, unfilled_samples(F)))}"
                 "</b>; "
                 f"{int((~observed.any(axis=1)).sum())} frame(s) with no marker observed.</p>")
    th = table_thresholds(rows)
    if th is not None:
        parts.append("<h2>Thresholds</h2><ul>" + "".join(f"<li>{esc(line)}</li>"
                                                        for line in th.lines()) + "</ul>")
        if not any(np.isfinite(r["est_rmse"]) for r in rows):
            parts.append("<p>No error estimate was given: the verdicts come from the "
                         "plausibility tests only.</p>")
    if rows:
        parts.append("<h2>Overview</h2><p class='legend'>"
                     + "".join(f"<span style='background:{c}'></span>{v}"
                               for v, c in COLOURS.items())
                     + "<span style='background:#9e9e9e'></span>left unfilled</p>")
        parts.append(overview_svg(rows, T, labels, first_frame,
                                  filled=np.isfinite(F).all(axis=2)))
    bad = sorted((r for r in rows if r["verdict"] != "ok"),
                 key=lambda r: (_ORDER[r["verdict"]], -(r["est_rmse"] if np.isfinite(r["est_rmse"])
                                                        else 0.0), -r["frames"]))
    if bad:
        empty = sum(r["filled_frames"] == 0 for r in bad)
        parts.append(f"<h2>Gaps to check ({len(bad)})</h2>" + (
            f"<p>{empty} of them left wholly unfilled (no figure: grey in the overview).</p>"
            if empty else ""))
        if len(bad) > max_figures:
            parts.append(f"<p>The {max_figures} worst are drawn; the table lists all.</p>")
        for r in bad[:max_figures]:
            if r["filled_frames"] == 0:
                continue
            svg = gap_figure(X, F, std, r, partners=partners_of.get(r["j"]), labels=labels,
                             units=units, first_frame=first_frame)
            parts.append(f"<figure id='gap-{r['j']}-{r['start']}' class='{r['verdict']}'>"
                         f"<figcaption><b>{esc(r['marker'])}</b> frames {r['first_frame']}-"
                         f"{r['last_frame']}: <b>{r['verdict']}</b> — "
                         f"{esc('; '.join(r['reasons']))}</figcaption>{svg}</figure>")
    parts.append(_gap_table_html(rows, u))
    parts.append(f"</tbody></table><script>{_SORT_JS}</script></body></html>")
    return "\n".join(parts)


def _gap_table_html(rows: list[dict], u: str) -> str:
    """The sortable table of every gap (opening tags and rows; the caller closes it)."""
    esc = html.escape
    cols = [("marker", "marker", "l"), ("first_frame", "first frame", ""),
            ("last_frame", "last frame", ""), ("frames", "frames", ""), ("kind", "kind", "l"),
            ("est_rmse", f"est. RMS error ({u})", ""), ("max_step", f"max step ({u})", ""),
            ("rigid_ratio", "rigid deviation (x spread)", ""),
            ("rigid_dev", f"rigid deviation ({u})", ""), ("support", "spatial support (%)", ""),
            ("unfilled", "unfilled frames", ""), ("verdict", "verdict", "l v"),
            ("reasons", "reasons", "l")]
    parts = ["<h2>All gaps</h2><p>Click a column head to sort.</p>"
                 "<table class='sortable'><thead><tr>"
                 + "".join(f"<th class='{cls}'>{head}</th>" for _, head, cls in cols)
                 + "</tr></thead><tbody>"]
    for r in sorted(rows, key=lambda r: (_ORDER[r["verdict"]], r["j"], r["start"])):
        cells = []
        for key, _, cls in cols:
            v = r[key]
            if key == "support":
                v = 100.0 * v
            if key == "reasons":
                v = "; ".join(v)
            if key == "verdict":
                sort = _ORDER[v]
            elif key == "marker":
                sort = v
            else:
                sort = v if isinstance(v, str) else (v if v is not None and np.isfinite(v) else "")
            cells.append(f"<td class='{cls}' data-v='{esc(str(sort))}'>"
                         f"{esc(v if isinstance(v, str) else _fmt(v, 4))}</td>")
        parts.append(f"<tr class='{r['verdict']}'>{''.join(cells)}</tr>")
    return "\n".join(parts)
