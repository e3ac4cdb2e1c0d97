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


# -- plausibility of a fill on real gaps (no truth needed) -----------------------------------------
# ``filled`` (T, J, 3) is a fill's output, ``missing`` (T, J) the samples it filled (NaN where a
# fill left a sample out counts as nothing); ``observed`` = ~missing & finite.

def norm_last(d) -> np.ndarray:
    """``np.linalg.norm(d, axis=-1)`` of a real array, the same bits: over a last axis shorter
    than 8 numpy's reduce adds the squares one after another, as here, without the reduce's cost
    on a short axis (a fifth of the time on (n, 3))."""
    d = np.asarray(d)
    if not 0 < d.shape[-1] < 8 or np.iscomplexobj(d):
        return np.linalg.norm(d, axis=-1)
    s = d[..., 0] * d[..., 0]
    for c in range(1, d.shape[-1]):
        s = s + d[..., c] * d[..., c]
    return np.sqrt(s)


def observed_steps(points, observed) -> np.ndarray:
    """Lengths of the one-frame steps between two observed samples of one marker."""
    X = np.asarray(points, dtype=np.float64)
    observed = np.asarray(observed, dtype=bool)
    both = observed[1:] & observed[:-1]
    s = None                    # norm_last(X[1:] - X[:-1]), one coordinate's (T-1, J) at a time
    for c in range(X.shape[-1]):
        d = X[1:, ..., c] - X[:-1, ..., c]
        s = d * d if s is None else s + d * d
    return np.sqrt(s)[both]


def step_limit(points, observed, *, q: float = 99.9, factor: float = 1.5) -> float:
    """``factor`` times the ``q``-th percentile of the observed steps (the teleport threshold)."""
    steps = observed_steps(points, observed)
    return float(factor * np.percentile(steps, q)) if steps.size else np.inf


def teleports(filled, missing, limit: float) -> int:
    """Steps longer than ``limit`` that touch a filled sample."""
    X = np.asarray(filled, dtype=np.float64)
    missing = np.asarray(missing, dtype=bool)
    touched = missing[1:] | missing[:-1]
    steps = np.linalg.norm(X[1:] - X[:-1], axis=2)
    return int(np.sum(touched & (steps > limit)))


def marker_jumps(filled, missing, observed, *, q: float = 99.9, factor: float = 1.5) -> int:
    """Steps touching a filled sample longer than ``factor`` times the ``q``-th percentile of THAT
    marker's own observed steps (:func:`step_limit` per marker): a shank marker's jump hidden
    under the recording-wide limit that the feet's fast steps set. Markers with no observed step
    count nothing."""
    X = np.asarray(filled, dtype=np.float64)
    missing, observed = np.asarray(missing, dtype=bool), np.asarray(observed, dtype=bool)
    return sum(teleports(X[:, j:j + 1], missing[:, j:j + 1],
                         step_limit(X[:, j:j + 1], observed[:, j:j + 1], q=q, factor=factor))
               for j in np.flatnonzero(missing.any(axis=0)))


def volume(points, observed, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis bounds of the observed samples, widened by ``margin`` times their range."""
    P, observed = np.asarray(points, dtype=np.float64), np.asarray(observed, dtype=bool)
    lo, hi = np.empty(P.shape[-1]), np.empty(P.shape[-1])
    for c in range(P.shape[-1]):                             # one axis's copy at a time
        axis = P[..., c][observed]
        lo[c], hi[c] = axis.min(), axis.max()
    return lo - margin * (hi - lo), hi + margin * (hi - lo)


def outside_volume(filled, missing, bounds: tuple[np.ndarray, np.ndarray]) -> int:
    """Filled samples outside ``bounds`` (see :func:`volume`) on any axis."""
    X = np.asarray(filled, dtype=np.float64)[np.asarray(missing, dtype=bool)]
    X = X[np.isfinite(X).all(axis=1)]
    return int(np.sum(((X < bounds[0]) | (X > bounds[1])).any(axis=1)))


def rigid_deviation(filled, missing, rigid, reference) -> np.ndarray:
    """``| |x_j - x_k| - d_jk |`` for every rigid pair (``rigid`` (J, J) bool, ``reference``
    (J, J) its observed distance) in every frame where either sample was filled."""
    X = np.asarray(filled, dtype=np.float64)
    missing = np.asarray(missing, dtype=bool)
    j, k = np.nonzero(np.triu(np.asarray(rigid, dtype=bool), 1))
    if j.size == 0:
        return np.zeros(0)
    d = np.linalg.norm(X[:, j] - X[:, k], axis=2)
    dev = np.abs(d - np.asarray(reference)[j, k])
    use = (missing[:, j] | missing[:, k]) & np.isfinite(dev)
    return dev[use]


def edge_jumps(filled, missing) -> np.ndarray:
    """Velocity jump at each interior gap edge: ``|v_in - v_out|``, where ``v_out`` is the last
    observed step before the edge and ``v_in`` the first step into the fill (both sides)."""
    X = np.asarray(filled, dtype=np.float64)
    T = X.shape[0]
    out = []
    for j, a, b in gap_runs(missing):
        if a >= 2:
            out.append(np.linalg.norm((X[a, j] - X[a - 1, j]) - (X[a - 1, j] - X[a - 2, j])))
        if b + 1 < T:
            out.append(np.linalg.norm((X[b + 1, j] - X[b, j]) - (X[b, j] - X[b - 1, j])))
    out = np.asarray(out, dtype=np.float64)
    return out[np.isfinite(out)]
