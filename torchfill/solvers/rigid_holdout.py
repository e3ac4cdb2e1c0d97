"""The hold-out error of a rigid carry: marker ``j`` carried between observed frames some lags
apart (:func:`_lag_pairs`), the RMS error per lag as a function of reach (:func:`_curve`), and
the same for a carry by two mates (:func:`_two_mates`); see :mod:`torchfill.solvers.rigid`.
"""
from __future__ import annotations

import numpy as np

from .rigid_batch import _turn

#: The hold-out error of a rigid fill is measured on at most this many reference frames per lag.
HOLDOUT_FRAMES = 64
#: Reaches (frames) at which the hold-out error is measured; interpolated in log reach between.
HOLDOUT_LAGS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096)
_LAGS = np.asarray(HOLDOUT_LAGS)


def _lag_pairs(refs: np.ndarray, reach: float = np.inf):
    """Reference frames ``src`` and the first ``dst`` at least each of ``HOLDOUT_LAGS`` frames
    later, up to the first lag that covers ``reach`` (longer lags change no estimate) and before
    the first with fewer than three pairs; at most ``HOLDOUT_FRAMES`` pairs per lag spread evenly
    (``numpy.linspace``'s picks); ``tag``: each pair's lag (index)."""
    lags = _LAGS[:int(np.searchsorted(_LAGS, reach)) + 1]
    c = np.searchsorted(refs, refs[-1] - lags, side="right") if refs.size else 0 * lags
    c = c[:int(np.argmax(c < 3)) if (c < 3).any() else c.size]    # the sources with a later ref
    m = np.minimum(c, HOLDOUT_FRAMES)
    tag = np.repeat(np.arange(c.size), m)
    ends = np.cumsum(m)
    y = (np.arange(tag.size) - np.repeat(ends - m, m)) * np.repeat((c - 1) / (m - 1), m)
    y[ends - 1] = c - 1
    pick = np.round(y).astype(np.int64)
    keep = np.ones(pick.size, dtype=bool)               # no pairs (too few refs): none
    keep[1:] = (pick[1:] != pick[:-1]) | (tag[1:] != tag[:-1])
    src, tag = refs[pick[keep]], tag[keep]
    return src, refs[np.searchsorted(refs, src + lags[tag])], tag


def _curve(src, dst, tag, sq, good) -> tuple[np.ndarray, np.ndarray]:
    """The hold-out error curve: per lag (``tag``) with three or more ``good`` pairs, the median
    reach ``dst - src`` and the RMS of the squared errors ``sq``; the errors made non-decreasing
    in reach."""
    d, tag, sq = (dst - src)[good], tag[good], sq[good]
    if d.size == 0:                                     # nothing measured: no curve
        return np.zeros(0), np.zeros(0)
    n = np.bincount(tag, minlength=1)
    order = np.lexsort((d, tag))
    first = np.cumsum(n) - n
    mid = (d[order][first + np.maximum(n - 1, 0) // 2] + d[order][first + n // 2]) / 2
    rms = np.sqrt(np.bincount(tag, weights=sq, minlength=1) / np.maximum(n, 1))
    three = n >= 3
    return mid[three].astype(float), np.maximum.accumulate(rms[three])


def _two_mates(X, seen, j, M, use, reach) -> np.ndarray:
    """Error (3-D RMS) of carrying ``j`` by two mates over ``reach`` frames, per frame whose
    mates seen are ``use`` (n, k), measured as the three-mate hold-out curve (:func:`_curve`)
    on the frames where ``j`` and those two are observed, carried by the smallest rotation of
    their line (the turn about it unseen); NaN where too few frames show the three together."""
    out = np.full(reach.size, np.nan)
    codes = use @ (1 << np.arange(M.size, dtype=np.int64))
    for code in np.unique(codes):
        pair = M[[i for i in range(M.size) if code >> i & 1][:2]]
        if pair.size < 2:
            continue
        refs = np.flatnonzero(seen[:, j] & seen[:, pair].all(axis=1))
        sel = codes == code
        src, dst, tag = _lag_pairs(refs, reach[sel].max())
        if src.size:
            P, Q = X[src][:, pair], X[dst][:, pair]
            R = _turn(P[:, 1] - P[:, 0], Q[:, 1] - Q[:, 0])
            x = np.einsum("ncd,nd->nc", R, X[src, j] - P.mean(axis=1)) + Q.mean(axis=1)
            lags, errs = _curve(src, dst, tag, np.sum((x - X[dst, j]) ** 2, axis=1),
                                np.ones(src.size, dtype=bool))
            out[sel] = np.interp(np.log(np.maximum(reach[sel], 1)), np.log(lags), errs)
    return out
