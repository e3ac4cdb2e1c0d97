"""Scores: marker RMSE over the hidden samples (all, at trial ends, interior; on the samples a
method filled), the error estimate's checks, and how right the per-gap verdicts are.

RMSE is per coordinate (mm) as :func:`torchfill.metrics.rmse_missing`; ``rmse3d`` is the 3-D
marker distance (the segment peers' table)."""
from __future__ import annotations

import numpy as np
from scipy.stats import spearmanr

from torchfill.metrics import gap_runs

#: A gap whose true RMS error is above BIG_MM and BIG_RATIO x the case's median should be flagged
#: (check or reject); one below SMALL_MM should be ok (docs/real-gaps.md#how-right-the-verdict-is).
BIG_MM, BIG_RATIO, SMALL_MM = 10.0, 3.0, 5.0
MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0}


def trial_end_mask(mask: np.ndarray) -> np.ndarray:
    """The hidden samples in gaps touching the first or last frame."""
    out = np.zeros_like(mask)
    T = mask.shape[0]
    for j, a, b in gap_runs(mask):
        if a == 0 or b == T:
            out[a:b, j] = True
    return out


def rmse(F: np.ndarray, truth: np.ndarray, on: np.ndarray) -> float:
    """RMSE per coordinate over the samples ``on`` (NaN when none, or any of them is unfilled)."""
    if not on.any():
        return float("nan")
    E = F[on] - truth[on]
    return float(np.sqrt(np.mean(E ** 2))) if np.isfinite(E).all() else float("nan")


def rmse3d(F: np.ndarray, truth: np.ndarray, on: np.ndarray) -> float:
    """RMSE of the 3-D marker distance over the samples ``on`` (NaN when none)."""
    if not on.any():
        return float("nan")
    return float(np.sqrt(np.mean(np.sum((F[on] - truth[on]) ** 2, axis=1))))


def marker_scores(F: np.ndarray, truth: np.ndarray, mask: np.ndarray,
                  rest: np.ndarray | None = None) -> dict:
    """``left`` (share of hidden samples ``F`` leaves missing), ``rmse_own`` (on the samples it
    filled) and, with the unfilled ones taken from ``rest``, ``rmse`` (all hidden samples),
    ``rmse_end`` (in gaps touching a trial end) and ``rmse_interior``."""
    filled = np.isfinite(F).all(axis=2)
    own = mask & filled
    out = {"left": 1.0 - own.sum() / max(int(mask.sum()), 1), "rmse_own": rmse(F, truth, own)}
    G = F if rest is None else np.where(filled[..., None], F, rest)
    end = trial_end_mask(mask)
    out.update(rmse=rmse(G, truth, mask), rmse_end=rmse(G, truth, end),
               rmse_interior=rmse(G, truth, mask & ~end))
    return out


def std_checks(filled, std, truth, mask) -> tuple[float, float, list]:
    """Spearman of per-gap estimated vs real error, share of filled coordinates within 2 std, and
    per gap (real RMS 3-D error, mean estimated std per coordinate)."""
    err = np.linalg.norm(filled - truth, axis=2)
    g = [(float(np.sqrt(np.mean(err[a:b, j] ** 2))), float(np.nanmean(std[a:b, j])))
         for j, a, b in gap_runs(mask)]
    ok = [x for x in g if np.isfinite(x[1])]
    rho = spearmanr([x[0] for x in ok], [x[1] for x in ok]).statistic if len(ok) > 2 else np.nan
    E = np.abs(filled - truth)[mask]                      # (n, 3) per coordinate
    s = std[mask][:, None]
    fin = np.isfinite(s[:, 0])
    within = float(np.mean(E[fin] <= 2 * s[fin])) if fin.any() else np.nan
    return float(rho), within, g


def verdicts(points, filled, truth, rate: float, labels, std=None, units: str = "mm",
             spatial: bool = False) -> list[dict]:
    """:func:`torchfill.qc.gap_table`'s rows (which never see the truth) plus each gap's true RMS
    error in mm (``true_mm``, NaN where nothing was filled) and whether it is ``big`` (should be
    flagged) or ``small`` (should be ok)."""
    from torchfill import qc

    rows = qc.gap_table(points, filled, rate, list(labels), std=std, units=units, spatial=spatial)
    scale = MM.get(units, 1.0)
    for r in rows:
        j, a, b = r["j"], r["start"], r["stop"]
        e = np.linalg.norm(filled[a:b, j] - truth[a:b, j], axis=1)
        e = e[np.isfinite(e)]
        r["true_mm"] = float(np.sqrt(np.mean(e ** 2))) * scale if e.size else np.nan
        r["est_mm"] = r["est_rmse"] * scale
    scored = [r["true_mm"] for r in rows if np.isfinite(r["true_mm"])]
    med = float(np.median(scored)) if scored else np.nan
    for r in rows:
        r["median_mm"] = med
        r["big"] = bool(r["true_mm"] > BIG_MM and r["true_mm"] > BIG_RATIO * med)
        r["small"] = bool(r["true_mm"] < SMALL_MM)
    return rows


def verdict_counts(rows: list[dict]) -> dict:
    """Big gaps and how many were flagged, small gaps and how many were ok (pooled over cases
    by summing; the accuracy is right / (big + small))."""
    big = [r for r in rows if r["big"]]
    small = [r for r in rows if r["small"]]
    return {"n_big": len(big), "big_flagged": sum(r["verdict"] != "ok" for r in big),
            "n_small": len(small), "small_ok": sum(r["verdict"] == "ok" for r in small)}


def verdict_accuracy(counts: list[dict]) -> tuple[float, float, float]:
    """(accuracy, share of big gaps flagged, share of small gaps ok) over summed ``counts``."""
    tot = {k: sum(float(c.get(k) or 0) for c in counts)
           for k in ("n_big", "big_flagged", "n_small", "small_ok")}
    share = lambda a, b: tot[a] / tot[b] if tot[b] else float("nan")  # noqa: E731
    n = tot["n_big"] + tot["n_small"]
    acc = (tot["big_flagged"] + tot["small_ok"]) / n if n else float("nan")
    return acc, share("big_flagged", "n_big"), share("small_ok", "n_small")
