"""The rigid reconstruction's work batched over markers and segments.

:func:`torchfill.solvers.rigid.segment_fill` estimates each marker of each segment in a
generator that yields its carries (:class:`_Fit`: marker ``j`` carried between frames by its
mates, each mate weighted by its consistency, then a weighted Kabsch fit) and, across a hole in
the mates, plain Kabsch fits (:class:`_Kabsch`, from :func:`_carry_few`); :func:`_drive` runs them
side by side and answers each round's requests in one array computation per mate count, a bounded
block of rows at a time. Every row's answer depends on that row alone: the same bits however the
rows are batched, so a segment's estimates are computed only at the samples it is chosen for.
"""
from __future__ import annotations

import numpy as np
import torch

from ..metrics import norm_last
from ..ops.rotation import kabsch

#: A mate is trusted in a frame while its distances to the other mates stay within this many
#: times their observed band (twice the robust spread plus the floor); see :func:`_consistency`.
CONSISTENT = 3.0
#: A carry with ``firm`` needs its mates' consistency factor above this (see :func:`_fit_block`).
FIRM = 0.5
#: Rows (frame pairs) of one block of the batched work: its temporaries stay a few megabytes.
ROWS = 1 << 13
#: The tasks of one wave of :func:`_drive` ask for about this many rows together (their requests
#: are held until answered): a long recording's memory does not grow with its length.
WAVE_ROWS = 1 << 18


class _Fit(list):
    """A request of :func:`_drive`: carries ``(j, M, W, src, dst, shape, firm)`` -- marker ``j``
    carried from frames ``src`` to ``dst`` by its mates ``M`` with weights ``W`` (n, k), each mate
    down-weighted by :func:`_consistency` with ``shape`` (``(D0, band)`` or None) in both frames.
    Answered by ``(estimate (n, 3), posed (n,))`` each: ``posed`` where ``firm`` is False or three
    mates keep a consistency above ``FIRM``."""


class _Kabsch(tuple):
    """A request of :func:`_drive`: :func:`kabsch` of ``(P, Q, W)`` (NumPy; answered in NumPy)."""


def _drive(tasks: list, X: np.ndarray | None = None, sizes=None) -> list:
    """Run the generators ``tasks`` side by side, in waves of about ``WAVE_ROWS`` rows by their
    ``sizes``: each round answers all of a wave's pending requests in one batched computation
    per mate count (a few large array operations instead of one small one per marker) on the
    positions ``X`` (NaN where not observed). Returns their return values in order."""
    out: list = [None] * len(tasks)
    if X is not None:                       # zeros for NaN once, and each coordinate's plane
        X = np.ascontiguousarray(X)                     # its rows taken flat (:func:`_fit_block`)
        X0 = np.nan_to_num(X)
        X = (X, X0, np.ascontiguousarray(X0.reshape(-1, X0.shape[2]).T))
    sizes = np.ones(len(tasks)) if sizes is None else np.asarray(sizes, float)
    wave = np.floor((np.cumsum(sizes) - sizes) / WAVE_ROWS)
    for w in np.unique(wave):
        asks: dict[int, object] = {}
        for i in np.flatnonzero(wave == w):
            _advance(tasks, i, None, asks, out)
        while asks:
            pending = list(asks.items())
            for (i, _), a in zip(pending, _answer(X, [r for _, r in pending])):
                _advance(tasks, i, a, asks, out)
    return out


def _advance(tasks, i, answer, asks, out) -> None:
    try:
        asks[i] = tasks[i].send(answer)
    except StopIteration as stop:
        out[i] = stop.value
        asks.pop(i, None)


def _answer(X, requests: list) -> list:
    """The answers to ``requests`` (:class:`_Fit` and :class:`_Kabsch`), grouped by mate count."""
    fits = _batched(lambda jobs: _fit_rows(X, jobs),
                    [job for r in requests if isinstance(r, _Fit) for job in r],
                    lambda job: (job[1].size, job[5] is None))
    kab = _batched(_kabsch_rows, [r for r in requests if isinstance(r, _Kabsch)],
                   lambda job: job[0].shape[1])
    fits, kab = iter(fits), iter(kab)
    return [[next(fits) for _ in r] if isinstance(r, _Fit) else next(kab) for r in requests]


def _batched(fn, jobs: list, kind) -> list:
    """``fn`` (a list of jobs of one ``kind``: mate count, ... -> their results) over ``jobs``,
    grouped by kind; the results in the jobs' order."""
    out: list = [None] * len(jobs)
    by_k: dict[object, list[int]] = {}
    for i, job in enumerate(jobs):
        by_k.setdefault(kind(job), []).append(i)
    for idx in by_k.values():
        for i, res in zip(idx, fn([jobs[i] for i in idx])):
            out[i] = res
    return out


def _fit_rows(X: tuple, jobs: list) -> list[tuple[np.ndarray, np.ndarray]]:
    """The answers to the carries ``jobs`` (one mate count), ``ROWS`` rows at a time."""
    n = np.array([job[3].size for job in jobs])
    ends = np.cumsum(n)
    starts = ends - n
    est, posed = np.empty((int(ends[-1]), 3)), np.empty(int(ends[-1]), dtype=bool)
    for a in range(0, int(ends[-1]), ROWS):
        b = min(a + ROWS, int(ends[-1]))
        inside = [i for i in range(np.searchsorted(ends, a, side="right"),
                                   np.searchsorted(starts, b)) if n[i]]
        cut = [(jobs[i], max(a - starts[i], 0), min(b, ends[i]) - starts[i]) for i in inside]
        est[a:b], posed[a:b] = _fit_block(X, cut)
    return list(zip(np.split(est, ends[:-1]), np.split(posed, ends[:-1])))


def _fit_block(X, cut: list) -> tuple[np.ndarray, np.ndarray]:
    """One block of :func:`_fit_rows`: the rows ``[a, b)`` of each job of ``cut``; ``X``: the
    positions, the same with zeros for NaN and its coordinates' planes (:func:`_drive`)."""
    part = [(j, M, W[a:b], src[a:b], dst[a:b], shape, firm)
            for (j, M, W, src, dst, shape, firm), a, b in cut]
    X, X0, planes = X
    J, n = X.shape[1], np.array([p[3].size for p in part])
    src, dst = (np.concatenate([p[c] for p in part]) for c in (3, 4))
    M = np.repeat(np.stack([p[1] for p in part]), n, axis=0)           # each row's mates
    at = [f[:, None] * J + M for f in (src, dst)]  # rows of (frame, mate) taken: a fast gather
    P, Q = (X0.reshape(-1, 3).take(i, axis=0) for i in at)
    W = np.concatenate([p[2] for p in part])
    firm = np.repeat([p[6] for p in part], n)
    C = _consistency_pairs(planes, np.concatenate(at), W > 0, part, n,
                           np.concatenate([src, dst]))
    if C is not None:
        W = W * C
    posed = ~firm | (((W > 0) & (C > FIRM)).sum(axis=1) >= 3 if C is not None else True)
    R, t = kabsch(*map(torch.from_numpy, (P, Q, W)))
    x = X.reshape(-1, 3).take(src * J + np.repeat([p[0] for p in part], n), axis=0)
    return np.einsum("nc,ndc->nd", x, R.numpy()) + t.numpy(), posed


def _consistency_pairs(planes, at, use, part, n, frames) -> np.ndarray | None:
    """:func:`_consistency` in the rows' source and destination frames (``frames`` and ``at``,
    the mates' flat indices into the coordinates' ``planes``: those of all rows, then these;
    ``n``: each job's rows), multiplied; each distinct (shape, frame, mates used) row computed
    once (a gap's frames are all carried from the same reference frame, and from both of its
    edges). None where the jobs have no shape."""
    if part[0][5] is None:
        return None
    k = use.shape[1]
    ids: dict[int, int] = {}
    shapes = [ids.setdefault(id(p[5]), len(ids)) for p in part]       # a task's carries share it
    one = [part[shapes.index(i)][5] for i in range(len(ids))]
    D0, band = np.stack([d for d, _ in one]), np.stack([b for _, b in one])
    job = np.repeat(shapes, n)
    job2, use2 = np.concatenate([job, job]), np.concatenate([use, use])
    if k + int(frames.max() + 1).bit_length() + len(ids).bit_length() < 62:
        key = ((job2 * (int(frames.max()) + 1) + frames) << k) + use2 @ (1 << np.arange(k))
        _, first, back = np.unique(key, return_index=True, return_inverse=True)
        job2, use2, at = job2[first], use2[first], at[first]
    else:                                                   # the key would overflow
        back = np.arange(job2.size)
    C = _consistency([x.take(at) for x in planes], use2, D0, band, job2)[back.reshape(-1)]
    return C[:job.size] * C[job.size:]


def _kabsch_rows(jobs: list) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`kabsch` of the requests ``jobs`` (one ``k``: ``(P, Q, W)``) in one batch."""
    R, t = kabsch(*(torch.from_numpy(np.concatenate(x)) for x in zip(*jobs)))
    cut = np.cumsum([j[0].shape[0] for j in jobs])[:-1]
    return list(zip(np.split(R.numpy(), cut), np.split(t.numpy(), cut)))


def _consistency(P: list, use: np.ndarray, D0: np.ndarray, band: np.ndarray,
                 shape: np.ndarray) -> np.ndarray:
    """Per frame and mate (n, k) of the mates' coordinates ``P`` (one (n, k) array each), a
    weight factor in (0, 1]: 1 while the mate's distances to the other used mates stay within
    ``CONSISTENT`` x their bands ``band`` of their medians ``D0`` (each ``(s, k, k)``, row ``i``
    taking ``shape[i]``; see :func:`_shape`), falling as
    ``(CONSISTENT / z)^2`` beyond, with ``z`` the lower median of the mate's deviations in
    bands: a ghost or a swapped label in a mate's track (one point far from its place in the
    segment) stops steering the fit, while one bad mate cannot condemn the good ones it is
    measured against. Each pair is measured once; the medians are sorted only where they leave
    the band."""
    k = use.shape[1]
    a, b = np.triu_indices(k, 1)
    Zp = np.abs(_pair_norms(P, a, b) - D0[:, a, b][shape]) / band[:, a, b][shape]
    used = use[:, a] & use[:, b] & np.isfinite(Zp)                     # pairs used
    mates = np.zeros((a.size, k))                                       # each pair's two mates
    mates[np.arange(a.size), a] = mates[np.arange(a.size), b] = 1.0
    n = used.astype(float) @ mates
    mid = np.maximum(np.floor((n - 1) * 0.5), 0.0)     # (n - 1) // 2 of counts, at least 0
    far = (n > 0) & (n - (used & (Zp > CONSISTENT)).astype(float) @ mates <= mid)
    C = np.ones(n.shape)                                   # the lower median within the band
    rows = np.flatnonzero(far.any(axis=1))
    if rows.size:
        at = np.full((k, k), a.size)                        # each mate's row of pairs: (m, k, k)
        at[a, b] = at[b, a] = np.arange(a.size)
        Z = np.where(used[rows], Zp[rows], np.inf)
        Z = np.concatenate([Z, np.full((rows.size, 1), np.inf)], axis=1)[:, at]
        S = np.sort(Z, axis=2)
        z = np.take_along_axis(S, mid[rows].astype(np.int64)[..., None], axis=2)[..., 0]
        C[rows] = np.where(far[rows], (CONSISTENT / np.maximum(z, CONSISTENT)) ** 2, 1.0)
    return C


def _pair_norms(P: list, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``norm_last`` of the differences of the points ``a`` and ``b`` (pairs of columns) of
    the coordinates ``P`` (one (n, k) array each), the same bits: the squares added one
    coordinate after another (a third of the time of (n, pairs, 3) gathers)."""
    s = None
    for Pc in P:
        d = Pc[:, a] - Pc[:, b]
        s = d * d if s is None else s + d * d
    return np.sqrt(s)


def _carry_few(P, Q, S, x, w) -> np.ndarray:
    """``x`` (n, 3) carried by the motion of the mates ``S`` (n, k) marks from ``P`` to ``Q``
    (n, k, 3): the weighted Kabsch fit with three or more, with two the smallest rotation taking
    the line through them in ``P`` to that in ``Q`` (the turn about that line is not seen) about
    their midpoint, with one its shift, with none ``x`` as it is."""
    n = S.sum(axis=1)
    row = np.arange(n.size)
    out = x.copy()
    many = n >= 3
    if many.any():
        R, tr = yield _Kabsch((np.nan_to_num(P[many]), np.nan_to_num(Q[many]), w * S[many]))
        out[many] = np.einsum("nc,ndc->nd", x[many], R) + tr
    first, second = np.argsort(~S, axis=1, kind="stable")[:, :2].T
    one = n == 1
    out[one] = (x + Q[row, first] - P[row, first])[one]
    two = n == 2
    if two.any():
        f, g, r = first[two], second[two], row[two]
        cp, cq = (P[r, f] + P[r, g]) / 2, (Q[r, f] + Q[r, g]) / 2
        R = _turn(P[r, g] - P[r, f], Q[r, g] - Q[r, f])
        out[two] = np.einsum("ncd,nd->nc", R, x[two] - cp) + cq
    return out


def _turn(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotations (n, 3, 3) taking the directions ``u`` to ``v`` (n, 3) (Rodrigues);
    the identity where they are opposite (no smallest one)."""
    u = u / norm_last(u)[:, None]
    v = v / norm_last(v)[:, None]
    k, c = np.cross(u, v), (u * v).sum(axis=1)
    K = np.zeros((u.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - K.transpose(0, 2, 1)
    R = np.eye(3) + K + K @ K / np.maximum(1 + c, 1e-12)[:, None, None]
    return np.where((c > -1 + 1e-9)[:, None, None], R, np.eye(3))
