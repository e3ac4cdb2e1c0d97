"""The rigid reconstruction's work batched over markers and segments.

:func:`torchfill.solvers.rigid.segment_fill` estimates each marker of each segment in a
generator that yields its consistency weights (:class:`_Shape`) and Kabsch fits
(:class:`_Kabsch`); :func:`_drive` runs them side by side and answers each round's requests in
one array computation per mate count, each request getting what it would get alone.
"""
from __future__ import annotations

import numpy as np
import torch

from ..metrics import norm_last
from ..ops.rotation import HORN_BLOCK, kabsch

#: A mate is trusted in a frame while its distances to the other mates stay within this many
#: times their observed band (twice the robust spread plus the floor); see :func:`_consistency`.
CONSISTENT = 3.0


class _Shape(list):
    """A request of :func:`_drive`: :func:`_consistency` of each ``(P, frames, use, shape)``."""


class _Kabsch(tuple):
    """A request of :func:`_drive`: :func:`kabsch` of ``(P, Q, W)`` (NumPy; answered in NumPy)."""


def _drive(tasks: list) -> list:
    """Run the generators ``tasks`` (:func:`_segment_estimate` of each marker and segment) side
    by side: each round answers all of their pending requests in one batched computation per
    mate count (a few large array operations instead of one small one per marker); each
    request's answer is what it would get alone. Returns their return values in order."""
    out: list = [None] * len(tasks)
    asks: dict[int, object] = {}

    def advance(i, answer):
        try:
            asks[i] = tasks[i].send(answer)
        except StopIteration as stop:
            out[i] = stop.value
            asks.pop(i, None)
    for i in range(len(tasks)):
        advance(i, None)
    while asks:
        pending = list(asks.items())
        answers = _answer([r for _, r in pending])
        for (i, _), a in zip(pending, answers):
            advance(i, a)
    return out


def _answer(requests: list) -> list:
    """The answers to ``requests`` (:class:`_Shape` and :class:`_Kabsch`), grouped by mate count."""
    jobs = [(r, n) for r in requests if isinstance(r, _Shape) for n in range(len(r))]
    shapes = _batched(_consistency_rows, [_unique_rows(*r[n]) for r, n in jobs])
    kab = _batched(_kabsch_rows, [r for r in requests if isinstance(r, _Kabsch)])
    shapes, kab = iter(shapes), iter(kab)
    return [[next(shapes) for _ in r] if isinstance(r, _Shape) else next(kab) for r in requests]


def _unique_rows(P, frames, use, shape):
    """``(P, use, D0, band, back)`` of the distinct (frame, mates used) rows: a gap's frames are
    all carried from the same reference frame."""
    k = use.shape[1]
    if k > 40:                                              # the key would overflow
        return P, use, *shape, None
    key = frames.astype(np.int64) * (1 << k) + use @ (1 << np.arange(k))
    _, first, back = np.unique(key, return_index=True, return_inverse=True)
    return P[first], use[first], *shape, back.reshape(-1)


def _batched(fn, jobs: list) -> list:
    """``fn`` (a list of jobs of one ``k`` -> their results) over ``jobs``, tuples whose first
    array is (n, k, ...), grouped by ``k``; the results in the jobs' order."""
    out: list = [None] * len(jobs)
    by_k: dict[int, list[int]] = {}
    for i, job in enumerate(jobs):
        by_k.setdefault(job[0].shape[1], []).append(i)
    for idx in by_k.values():
        for i, res in zip(idx, fn([jobs[i] for i in idx])):
            out[i] = res
    return out


#: Rows of one batched consistency computation (its (n, k, k) arrays stay small).
ROWS = 1 << 14
#: Rows of one :func:`kabsch` call: its temporaries stay a few times one block's points, whatever
#: the recording's length; a multiple of ``HORN_BLOCK``, so that each rotation is solved among
#: the same neighbours as in one call over all rows (the same bits).
KABSCH_ROWS = 2 * HORN_BLOCK


def _consistency_rows(jobs: list) -> list[np.ndarray]:
    """:func:`_consistency` of the rows of ``jobs`` (one ``k``: ``(P, use, D0, band, back)``),
    each job's shape per row, expanded back to every row of its request (``back``)."""
    reps = [j[0].shape[0] for j in jobs]
    D0, band = np.stack([j[2] for j in jobs]), np.stack([j[3] for j in jobs])
    job = np.repeat(np.arange(len(jobs)), reps)     # each row's shape, taken a block at a time
    C = np.concatenate([_consistency(P, use, D0[job[a:a + ROWS]], band[job[a:a + ROWS]])
                        for a, (P, use) in zip(range(0, job.size, ROWS),
                                               _blocks([j[:2] for j in jobs], ROWS))])
    parts = np.split(C, np.cumsum(reps)[:-1])
    return [c if j[4] is None else c[j[4]] for c, j in zip(parts, jobs)]


def _kabsch_rows(jobs: list) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`kabsch` of the requests ``jobs`` (one ``k``: ``(P, Q, W)``) in one batch."""
    R, t = (torch.cat(x) for x in zip(*[kabsch(*map(torch.from_numpy, block))
                                        for block in _blocks(jobs, KABSCH_ROWS)]))
    cut = np.cumsum([j[0].shape[0] for j in jobs])[:-1]
    return list(zip(np.split(R.numpy(), cut), np.split(t.numpy(), cut)))


def _blocks(jobs: list, size: int):
    """The concatenations over ``jobs`` (tuples of arrays with one row per job's item) of each
    tuple member, ``size`` rows at a time (at least one block, perhaps empty), without building
    the whole concatenation."""
    ends = np.cumsum([j[0].shape[0] for j in jobs])
    starts = ends - [j[0].shape[0] for j in jobs]
    for a in range(0, max(int(ends[-1]), 1), size):
        b = a + size
        inside = [i for i in range(np.searchsorted(ends, a, side="right"),
                                   np.searchsorted(starts, b)) if ends[i] > starts[i]] or [0]
        yield tuple(np.concatenate([jobs[i][m][max(a - starts[i], 0):b - starts[i]]
                                    for i in inside]) for m in range(len(jobs[0])))


def _consistency(P: np.ndarray, use: np.ndarray, D0: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Per frame and mate (n, k), a weight factor in (0, 1]: 1 while the mate's distances to the
    other used mates stay within ``CONSISTENT`` x their bands ``band`` (k, k) of their medians
    ``D0`` (k, k) (see :func:`_shape`), falling as ``(CONSISTENT / z)^2`` beyond, with ``z`` the
    lower median of the mate's deviations in bands: a ghost or a swapped label in a mate's track
    (one point far from its place in the segment) stops steering the fit, while one bad mate
    cannot condemn the good ones it is measured against."""
    D = norm_last(P[:, :, None] - P[:, None])
    Z = np.abs(D - D0) / band
    pair = use[:, :, None] & use[:, None] & np.isfinite(Z)
    pair &= ~np.eye(P.shape[1], dtype=bool)
    Z = np.where(pair, Z, np.inf)
    n = pair.sum(axis=2)
    S = np.sort(Z, axis=2)
    z = np.take_along_axis(S, np.clip((n - 1) // 2, 0, None)[..., None], axis=2)[..., 0]
    z = np.where(n > 0, z, 0.0)
    return (CONSISTENT / np.maximum(z, CONSISTENT)) ** 2
