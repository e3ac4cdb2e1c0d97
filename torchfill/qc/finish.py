"""What the fill's finishing step takes from the QC: an error estimate bounded by what the fill
can be off, and short gaps kept on the interpolation across them when the fill departs from it
by more than its estimate allows (pure functions of the input, the fill and its estimate; the
truth is never seen). Measured in docs/real-gaps.md ("How right the verdict is").
"""
from __future__ import annotations

import math

import numpy as np

from .. import metrics
from ..constraints import STEP_FACTOR, STEP_PERCENTILE
from .verdicts import AGREE_MM, SHORT_SECONDS

#: Interior gaps up to this many frames (and ``SHORT_SECONDS``) are kept on the interpolation
#: across them when the fill departs from it by more than ``AGREE_MM``: on such gaps the
#: interpolation errs by 0.1 mm (median), so a larger departure is the fill's error, and the
#: fill's estimate does not see it (docs/real-gaps.md, "Short gaps").
SHORT_FRAMES = 10
#: Observed steps a marker needs for its own step limit; with fewer, the recording's.
OWN_STEPS = 20


def std_bound(points, filled, dims: int | None = None) -> np.ndarray:
    """``(T, J)`` the largest per-coordinate error std a filled sample can have: its 3-D error
    is at most the fill's distance from the gap's nearest observed edge sample plus how far the
    marker can move in the frames between (its own step limit -- ``STEP_FACTOR`` x its
    ``STEP_PERCENTILE``-th percentile observed step, the recording's with fewer than
    ``OWN_STEPS`` -- per frame), and at most the observed volume's diagonal (both stay inside
    it); divided by sqrt(D). ``inf`` where there is no bound (observed samples, no observed
    edge), NaN never."""
    X = np.asarray(points, dtype=np.float64)
    F = np.asarray(filled, dtype=np.float64)
    T, J, D = X.shape
    D = dims or D
    observed = np.isfinite(X).all(axis=2)
    out = np.full((T, J), np.inf)
    if not observed.any():
        return out
    lo, hi = metrics.volume(X, observed, 0.0)
    diagonal = float(np.linalg.norm(hi - lo))
    whole = metrics.step_limit(X, observed, q=STEP_PERCENTILE, factor=STEP_FACTOR)
    frames = np.arange(T)
    for j in np.flatnonzero(observed.any(axis=0) & ~observed.all(axis=0)):
        own = observed[:, j]
        cap = (metrics.step_limit(X[:, [j]], own[:, None], q=STEP_PERCENTILE, factor=STEP_FACTOR)
               if (own[1:] & own[:-1]).sum() >= OWN_STEPS else whole)
        gap = ~own
        best = np.full(int(gap.sum()), np.inf)
        before = np.maximum.accumulate(np.where(own, frames, -1))[gap]     # nearest edges
        after = np.minimum.accumulate(np.where(own, frames, T)[::-1])[::-1][gap]
        for edge in (before, after):
            ok = (edge >= 0) & (edge < T)
            e = edge[ok]
            away = (np.linalg.norm(F[gap, j][ok] - X[e, j], axis=1)
                    + np.abs(frames[gap][ok] - e) * cap)
            best[ok] = np.fmin(best[ok], away)
        out[gap, j] = np.minimum(best, diagonal) / math.sqrt(D)
    return out


def short_gap_fallback(points, filled, rate: float | None, per_mm: float = 1.0,
                       side: int = 4, keep=None
                       ) -> tuple[np.ndarray, list[tuple[int, int, int]], np.ndarray]:
    """``(filled, gaps, departure)``: a copy of ``filled`` where each interior gap of up to
    ``SHORT_FRAMES`` frames and ``SHORT_SECONDS`` (``rate`` in Hz; None: frames only) whose fill
    departs (RMS, 3-D) from the PCHIP interpolation through up to ``side`` observed samples on
    each side by more than ``AGREE_MM`` (``per_mm``: file units per mm) holds that interpolation
    instead; those gaps ``(j, start, stop)``; and ``(T, J)`` each such gap's per-frame distance
    between the given fill and the interpolation, for every short gap compared (kept or
    replaced), NaN elsewhere. Gaps not wholly filled are left as they are. ``keep`` (T, J, D
    bool): ``filled`` itself is changed, except where ``keep`` (no copy: a long recording's
    fill is hundreds of MB)."""
    X = np.asarray(points, dtype=np.float64)
    F = np.array(filled, dtype=np.float64, copy=keep is None)
    T = X.shape[0]
    observed = np.isfinite(X).all(axis=2)
    departure = np.full(observed.shape, np.nan)
    longest = min(SHORT_FRAMES, int(SHORT_SECONDS * rate + 1e-9) if rate else SHORT_FRAMES)
    groups: dict[tuple, list] = {}                  # gaps sharing their knots' layout
    for j, a, b in metrics.gap_runs(~observed):
        if a == 0 or b == T or b - a > longest or not np.isfinite(F[a:b, j]).all():
            continue
        t = np.r_[np.arange(max(0, a - side), a), np.arange(b, min(T, b + side))]
        t = t[observed[t, j]]
        if t.size >= 2:
            groups.setdefault((b - a, tuple(t - a)), []).append((j, a, b, t))
    changed = []
    for (n, knots), gaps in groups.items():
        P = _pchip(np.asarray(knots, dtype=np.float64), X, gaps, n)      # (n, gaps, D)
        for k, (j, a, b, _) in enumerate(gaps):
            departure[a:b, j] = np.linalg.norm(F[a:b, j] - P[:, k], axis=1)
            if math.sqrt(np.mean(departure[a:b, j] ** 2)) > AGREE_MM * per_mm:
                F[a:b, j] = P[:, k] if keep is None else np.where(keep[a:b, j], F[a:b, j], P[:, k])
                changed.append((int(j), int(a), int(b)))
    return F, sorted(changed), departure


def finish(points, filled, std, rate: float | None, per_mm: float = 1.0, keep=None
           ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int]]]:
    """``(filled, std, gaps)``: the fill with its short gaps finished (:func:`short_gap_fallback`,
    ``gaps`` those replaced) and its per-coordinate ``std`` (T, J) raised, on every short gap
    compared, to the given fill's distance from the interpolation over sqrt(D) -- one of the
    two is off by about that much, and the finished fill holds the interpolation only where they
    disagree -- then cut to :func:`std_bound`. NaN std stays NaN."""
    X = np.asarray(points, dtype=np.float64)
    F, changed, departure = short_gap_fallback(X, filled, rate, per_mm, keep=keep)
    S = np.asarray(std, dtype=np.float64)
    raise_ = np.isfinite(departure) & np.isfinite(S)
    S = np.where(raise_, np.fmax(S, departure / math.sqrt(X.shape[2])), S)
    return F, np.minimum(S, std_bound(X, F)), changed


def _pchip(knots: np.ndarray, X: np.ndarray, gaps: list, n: int) -> np.ndarray:
    """PCHIP through the samples at ``knots`` (frames relative to each gap's start) of every gap
    of ``gaps`` at once, evaluated at its ``n`` frames: (n, gaps, D)."""
    from scipy.interpolate import PchipInterpolator

    Y = np.stack([X[t, j] for j, _, _, t in gaps], axis=1)                  # (knots, gaps, D)
    return PchipInterpolator(knots, Y, axis=0)(np.arange(n, dtype=np.float64))
