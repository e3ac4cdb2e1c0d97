"""Accuracy metrics: pure functions of (filled, truth, mask). Inputs are arrays ``(T, J, D)`` (D = 3
for markers, 2 for image keypoints) and a gap mask ``(T, J)`` (True = the sample was missing and has
been filled).

Two conventions coexist in the papers, and both are here:

* over **all** T*J*3 entries, observed ones counting with zero error (Mohaoui & Dmytryshyn 2024,
  2026: ``rmse``, ``ave``, ``std``);
* over the **missing** entries only (Imamura & Okuda 2018 Eq. 23: ``rmse_missing``) and per gap in
  3-D (Li et al. 2020 Eq. 17: ``gap_error``).
"""
from __future__ import annotations

import numpy as np


def _error(filled, truth, mask) -> tuple[np.ndarray, np.ndarray]:
    filled, truth = np.asarray(filled, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if filled.shape != truth.shape or filled.shape[:2] != mask.shape:
        raise ValueError(f"shapes differ: filled {filled.shape}, truth {truth.shape}, mask {mask.shape}")
    E = np.where(mask[..., None], filled - truth, 0.0)
    return E, mask


def rmse(filled, truth, mask) -> float:
    """Root mean square error over all T*J*3 entries (observed entries count as zero error)."""
    E, _ = _error(filled, truth, mask)
    return float(np.sqrt(np.mean(E ** 2)))


def ave(filled, truth, mask) -> float:
    """Average absolute error over all T*J*3 entries (Tucker/CP papers' AvE)."""
    E, _ = _error(filled, truth, mask)
    return float(np.mean(np.abs(E)))


def std(filled, truth, mask) -> float:
    """Standard deviation of the absolute error over all entries (Tucker/CP papers' STD)."""
    E, _ = _error(filled, truth, mask)
    return float(np.std(np.abs(E)))


def rmse_missing(filled, truth, mask) -> float:
    """RMSE over the missing entries only (each coordinate an entry; Imamura & Okuda Eq. 23)."""
    E, mask = _error(filled, truth, mask)
    n = E.shape[2] * mask.sum()
    return float(np.sqrt((E ** 2).sum() / n)) if n else 0.0


def gap_runs(mask) -> list[tuple[int, int, int]]:
    """Every gap as ``(marker, start, stop)`` (stop exclusive), markers in order."""
    mask = np.asarray(mask, dtype=bool)
    runs = []
    for j in range(mask.shape[1]):
        padded = np.concatenate(([False], mask[:, j], [False])).astype(np.int8)
        edges = np.flatnonzero(np.diff(padded))
        runs.extend((j, int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]))
    return runs


def gap_error(filled, truth, mask) -> float:
    """Mean over gaps of the mean Euclidean (3-D, or 2-D for keypoints) error inside the gap
    (Li et al. 2020 Eq. 17)."""
    E, mask = _error(filled, truth, mask)
    d = np.linalg.norm(E, axis=2)
    runs = gap_runs(mask)
    return float(np.mean([d[a:b, j].mean() for j, a, b in runs])) if runs else 0.0


def frame_rmse(filled, truth, mask) -> np.ndarray:
    """Per-frame RMSE over the frame's missing coordinates (NaN where nothing is missing)."""
    E, mask = _error(filled, truth, mask)
    n = E.shape[2] * mask.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt((E ** 2).sum(axis=(1, 2)) / np.maximum(n, 1)), np.nan)


def score(filled, truth, mask) -> dict[str, float]:
    """Every scalar metric above, by name."""
    return {f.__name__: f(filled, truth, mask)
            for f in (rmse, ave, std, rmse_missing, gap_error)}
