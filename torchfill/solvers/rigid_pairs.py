"""Rigid pairs of the data: near-neighbour marker pairs whose distance is nearly constant.

Only each marker's nearest neighbours are measured (:func:`torchfill.segments.neighbour_pairs`),
so the cost grows linearly with the markers; :mod:`torchfill.constraints` keeps the rigid
pairs' distances softly and the QC checks them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .. import segments as _segments

Tensor = torch.Tensor


@dataclass
class RigidPairs:
    """Near-neighbour marker pairs and how rigid they are (one entry per pair ``(j[i], k[i])``,
    ``j < k``; NumPy arrays)."""

    j: np.ndarray
    k: np.ndarray
    distance: np.ndarray    # median distance while both are observed (NaN: too rarely together)
    spread: np.ndarray      # robust spread of that distance (1.4826 x MAD)
    rigid: np.ndarray       # bool: spread <= tol * scale
    duplicate: np.ndarray   # bool: one marker stored twice (distance <= tol * scale)
    scale: float            # median pairwise distance: the body's size
    J: int                  # markers in the recording
    tol: float = 0.005      # the rigidity tolerance, relative to ``scale``
    wide: np.ndarray | None = None  # 95th percentile of |distance - median| while both observed
    direction: np.ndarray | None = None  # (n, 3) mean unit vector from k to j while both observed
    cone: np.ndarray | None = None  # 95th percentile angle (radians) to ``direction`` then
    cover: np.ndarray | None = None  # share of the frames in which both are observed

    def matrix(self, values, fill=np.nan) -> np.ndarray:
        """A dense symmetric ``(J, J)`` array of per-pair ``values`` (for small J: reports)."""
        v = np.asarray(values)
        out = np.full((self.J, self.J), fill, dtype=v.dtype if v.dtype == bool else np.float64)
        out[self.j, self.k] = out[self.k, self.j] = v
        return out


#: Pair distances are measured this many (frame, pair) entries at a time.
PAIR_BLOCK = _segments.PAIR_BLOCK
#: Pair statistics read at most this many frames, evenly spaced: their sort took 23 of the
#: constraints' 30 s at 120 000 frames; 12 000 leaves every recording of ../shared/data whole.
PAIR_FRAMES = 12000
#: The body's size is the median distance of all pairs up to this many markers, else of this
#: many pairs' worth of random pairs (the median of 20 000 pairs is within a percent of all).
SCALE_PAIRS = 20000


def rigid_pairs(X, observed=None, *, tol: float = 0.005, min_frames: int = 20,
                pairs: tuple[np.ndarray, np.ndarray] | None = None) -> RigidPairs:
    """Find rigid marker pairs among near neighbours from the frames where both are observed.

    Parameters
    ----------
    X : tensor or array (T, J, 3)
        Marker positions; NaN where missing.
    observed : bool (T, J), optional
        Observed samples (default: the finite ones).
    tol : float
        Rigid when the distance's robust spread is at most ``tol`` times the median pairwise
        distance (``tol = 0.005`` is about 3 mm on an adult body; 0.01 lets neck and shoulder
        pairs in; chosen on simulated gaps of HDM05, CMU and Kinetics Toolkit recordings).
    min_frames : int
        Pairs seen together in fewer frames are never rigid.
    pairs : (j, k) arrays, optional
        The pairs to measure (default: :func:`torchfill.segments.neighbour_pairs`; all pairs for
        up to ``NEIGHBOURS + 1`` markers).

    A recording longer than ``PAIR_FRAMES`` frames is read at every ``stride``-th frame.
    """
    X = _numpy(X)
    observed = np.isfinite(X).all(axis=2) if observed is None else _numpy(observed).astype(bool)
    _segments.PAIR_FRAMES, _segments.PAIR_BLOCK = PAIR_FRAMES, PAIR_BLOCK
    J = X.shape[1]
    st = every = None
    if pairs is None and J * (J - 1) // 2 <= SCALE_PAIRS:    # the scale measures every pair:
        near = _segments.neighbour_pairs(X, observed)     # their orientation and spread only
        a, b = np.triu_indices(J, 1)
        turn = np.isin(a * J + b, near[0] * J + near[1])
        every = _segments.pair_stats(X, observed, (a, b), min_frames=min_frames,
                                     orientation=turn, spread=turn)
        st = _subset(every, near)                       # each pair on its own
    if st is None:
        st = _segments.pair_stats(X, observed, pairs, min_frames=min_frames)
        every = st
    scale = _scale(X, observed, every, min_frames)
    finite = np.isfinite(st.distance)
    duplicate = finite & (st.distance <= tol * scale)
    rigid = finite & (st.spread <= tol * scale)
    frames = -(-X.shape[0] // -(-X.shape[0] // PAIR_FRAMES))         # the frames pair_stats read
    return RigidPairs(st.j, st.k, st.distance, st.spread, rigid, duplicate, scale, J, tol, st.wide,
                      st.direction, st.cone, st.count / max(frames, 1))


def _subset(st: "_segments.PairStats", pairs: tuple[np.ndarray, np.ndarray]
            ) -> "_segments.PairStats | None":
    """The statistics of ``pairs`` taken from ``st`` (None unless ``st`` measured each of them):
    a pair's statistics depend on its own two tracks only, so these are the bits
    :func:`torchfill.segments.pair_stats` gives for ``pairs`` alone."""
    j, k = (np.asarray(p, dtype=np.int64) for p in pairs)
    order = np.lexsort((k, j))
    i = st.lookup(j[order], k[order])
    if (i < 0).any():                                   # a pair (j, j) of a stored-twice point
        return None
    return _segments.PairStats(st.j[i], st.k[i], st.distance[i], st.spread[i], st.wide[i],
                               st.count[i], st.J, st.direction[i], st.cone[i])


def _scale(X, observed, st, min_frames) -> float:
    """Median pairwise distance over all pairs (or ``SCALE_PAIRS`` random ones)."""
    J = X.shape[1]
    if J * (J - 1) // 2 <= SCALE_PAIRS:
        a, b = np.triu_indices(J, 1)
    else:
        rng = np.random.default_rng(0)
        a = rng.integers(0, J, SCALE_PAIRS)
        b = rng.integers(0, J, SCALE_PAIRS)
        keep = a != b
        a, b = np.minimum(a, b)[keep], np.maximum(a, b)[keep]
    if st.j.size == a.size and np.array_equal(st.j, a) and np.array_equal(st.k, b):
        d = st.distance
    else:
        d = _segments.pair_stats(X, observed, (a, b), min_frames=min_frames).distance
    d = d[np.isfinite(d)]
    return float(np.median(d)) if d.size else 1.0


def body_size(X: np.ndarray, seen: np.ndarray, frames: int = 50) -> float:
    """The median distance between the markers seen together, over ``frames`` evenly spaced
    frames with the most markers seen: the body's size in the data's units (cheap: no pairs'
    statistics over time)."""
    count = seen.sum(axis=1)
    order = np.argsort(-count, kind="stable")[:max(frames, 1)]
    d = []
    for t in order:
        P = X[t, seen[t]]
        if len(P) > 1:
            i, k = np.triu_indices(len(P), 1)
            d.append(np.linalg.norm(P[i] - P[k], axis=1))
    return float(np.median(np.concatenate(d))) if d else 1.0


def _numpy(X) -> np.ndarray:
    if isinstance(X, torch.Tensor):
        return X.detach().cpu().numpy()
    return np.asarray(X)


def _upper_nanquantile(D: Tensor, q: float) -> Tensor:
    """``torch.nanquantile(D, q, dim=0)`` (linear interpolation) for ``q >= 0.5`` from the top
    ``(1 - q) T + 2`` values of each column (a partial selection, not a full sort: 72 vs 223 ms
    for 3 000 frames x 820 pairs); the same values."""
    T = D.shape[0]
    n = (~torch.isnan(D)).sum(dim=0)
    k = min(T, int((1 - q) * (T - 1)) + 2)
    top = torch.topk(torch.nan_to_num(D, nan=-torch.inf), k, dim=0).values     # descending
    p = q * (n - 1).clamp(min=0).to(D.dtype)
    lo, hi = p.floor().long(), p.ceil().long()
    below, above = (top.gather(0, ((n - 1) - i).clamp(0, k - 1)[None])[0] for i in (lo, hi))
    return torch.where(n > 0, torch.lerp(below, above, p - lo.to(D.dtype)), torch.nan)
