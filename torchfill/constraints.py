"""Constraints that make any method's fill obey the body on real gaps; ``fill()`` applies them by
default (``constraints=False`` returns the method's own fill, as in the papers).

Real gaps differ from the papers' protocols: they cluster at trial ends and where several markers
hide at once, and a low-rank reconstruction of a frame jumps when the set of observed markers
changes. The post-step below takes the method's fill and, in this order:

1. **rigid donors**: every missing sample with >= 3 observed rigid partners (or an observed
   duplicate) is replaced by the rigid-body fill of :mod:`torchfill.solvers.rigid`;
2. **extrapolation limit**: a gap touching the first or last frame keeps at most ``extrapolate``
   frames of the method's fill next to its observed edge; the rest is left NaN with a warning;
3. **blackouts**: frames in which no marker is observed are not invented by the method: their
   samples are interpolated linearly in time from the fill around them (NaN at the trial ends);
4. **continuity at gap edges**: the fill is offset so that its first and last samples continue
   the observed trajectory in position and velocity (``x[a-1] + v``), the offset blended linearly
   across the gap (a gap touching a trial end: faded out over ``END_FADE`` frames);
5. **soft rigid distances**: a filled sample whose distance to a rigid partner strays more than
   ``SOFT_BAND`` times the pair's observed spread is moved back towards that band — for pairs
   whose observed distances stay within ``SOFT_WIDE`` bands in 95 % of their frames (a
   median-based spread also calls a pair rigid that is still most of the time and bends now and
   then: on hdm05_bd_05-01 such a pair took one 208-frame gap from 2.5 to 46 mm); the band of
   that test is at least the rigidity tolerance (a pair seen almost still has a tiny band),
   a pair seen turning less than ``SOFT_CONE`` while observed (its distance measured only
   while the joints between its markers were still) gets the chord of a fill's turn beyond
   that range added to its band, in proportion to the frames it was not seen in,
   ``SOFT_ITER`` Jacobi iterations of weight ``SOFT_WEIGHT`` (a position-
   based projection, as MocapRecovery's skeleton constraint keeps neighbour distances), on
   ``auto``'s average too, although its candidates each went through it: without it the
   real-gap suite's mean moved by 0.06 mm while segments tore on the real gaps of
   walking_hybrid_1_4 filled whole (21 gaps with a rigid partner more than 3 spreads off
   against 15, the largest deviation 103 mm against 42);
6. **no teleports**: inside each gap, one-frame steps longer than 1.5 x the recording's 99.9th
   percentile observed step are shortened, the gap's end mismatch spread over all its steps
   (repeated; linear interpolation if that cannot meet the limit); a gap held at one edge only
   (touching a trial end) has no far edge that may need a fast move, and its steps are held to
   the 99.9th percentile itself (``END_STEP_FACTOR``);
7. **capture volume**: filled samples are clamped into the per-axis range of the observed ones,
   widened by ``VOLUME_MARGIN`` of that range (a short trial's observed range is not the whole
   volume: a marker missing at the start may lie behind every observed sample).

Observed samples are never changed.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from .metrics import gap_runs, norm_last, step_limit, volume
from .runtime.cache import Memo
from .solvers.rigid import RigidPairs, rigid_fill, rigid_pairs

#: Weight of one soft-distance projection step (0 = off, 1 = full projection each iteration).
SOFT_WEIGHT = 0.5
#: A rigid pair's distance may stray this many times its observed spread before it is corrected.
SOFT_BAND = 3.0
#: Jacobi iterations of the soft-distance projection.
SOFT_ITER = 10
#: Soft distances hold a pair only if 95 % of its observed distances lie within this many bands
#: of its median (a median-based spread alone also calls a pair rigid that bends now and then).
#: Of 1 / 2 / 3 / 5 / off, 3 was never worse than off and better on hdm05 (bench_long 3000
#: frames 4.90 -> 1.96 mm, constraints_tucker gap 100 0.72 -> 0.62); 1 lost on constraints_cp.
#: The band of this test is at least ``tol x scale`` of the rigid pairs: numediart_03_rolling's
#: LR_FM5-LR_FM2 (spread 0.11 mm, p95 4.7 mm) was dropped and torn to 299 mm (now 193 mm).
SOFT_WIDE = 3.0
#: A rigid pair seen turning (95th-percentile angle around its mean direction) by less than this
#: many radians has not shown that its distance holds as the joints between its markers move: a
#: fill that turns it further gets the chord of the extra turn added to its band (see
#: :func:`_unseen_turn`). numediart_03_rolling's mask on hdm05_bd_05-01: the pairs of an
#: upper-arm marker seen only while still turned 0.024-0.040; the head, forearm and thigh pairs
#: of codamotion's mask on cmu_135_02 turned 0.10-1.7, and widening theirs lost 22.6 -> 27.3 mm.
SOFT_CONE = 0.1
#: Soft distances are projected on this many (frame, pair) entries at a time.
SOFT_BLOCK = 1 << 18
#: Observed markers a frame needs for a spatial method's trial-end fill there not to count as an
#: extrapolation in time (three markers fix a rigid body's pose).
SPATIAL_MIN = 3
#: Share of the observed per-axis range a fill may lie outside it.
VOLUME_MARGIN = 0.1
#: A fill's one-frame step may not exceed STEP_FACTOR x this percentile of the observed steps
#: (1.0 x the 99.9th percentile clipped true fast motion in simulated gaps on HDM05: +75 % RMSE).
STEP_PERCENTILE = 99.9
STEP_FACTOR = 1.5
#: The same for a fill held at one edge only (a gap touching a trial end): the 1.5 x allowance
#: lets a fill pinned at both edges cover a fast move; a trial-end fill has no far edge to reach,
#: and on c3dorg_s26_walking_hybrid_1_1 the default's trial-start fills, from 3-5 markers seen,
#: moved 30-35 mm per frame (the observed 99.9th percentile: 23 mm).
END_STEP_FACTOR = 1.0
#: A gap held at one edge only (touching a trial end) takes its edge offset over this many frames,
#: fading linearly to none: the offset (the observed trajectory continued by one frame's velocity,
#: minus the fill) is mostly the edge's acceleration, and carried over the whole gap it moved
#: right spatial fills off (on the samples gapfill's rigid-body fill reaches, measured with
#: auto's average outside the soft distances: the default's mean 0.92 -> 0.85 x gapfill's RMSE,
#: s28_type1's mask on cmu_85_02 1.74 -> 1.06; fading over the whole gap there 1.36, over 30
#: frames 1.28). Continuing the acceleration too and keeping the
#: shift instead won one recording (hamner running 0.68 x) and a model's bias at the far end
#: (walking_hybrid_1_5's session fill on cmu_85_02: 18.3 mm, faded 49.2), but lost gapfill's
#: samples (mean 0.87, numediart's layout mask 1.92 x) and joint angles (IK: worse than the gaps
#: on ktk_basket_sprint's mask again, 14.61 vs 14.07 deg; gait masks 0.46 -> 0.77 deg).
END_FADE = 10


class RiskyFillWarning(UserWarning):
    """A fill that needs checking: extrapolated, long, without donors, or across a blackout."""


@dataclass
class ConstraintReport:
    """What the constraints did (counts of samples / gaps), for ``qc`` and the warnings."""

    rigid: int = 0
    blackout_frames: int = 0
    extrapolated_gaps: list = field(default_factory=list)   # (marker, start, stop) of the fill
    unfilled_extrapolation: int = 0                         # samples left NaN by the limit
    spatial_samples: int = 0            # trial-end samples kept: markers seen in the same frame
    time_samples: int = 0               # trial-end samples kept: extrapolated in time
    shortened_gaps: int = 0
    clamped: int = 0
    rigid_done: np.ndarray | None = None                    # (T, J) filled by rigid donors
    step_limit: float = float("inf")
    end_step_limit: float = float("inf")                    # gaps touching a trial end
    long_gaps: list = field(default_factory=list)            # long gaps without rigid donors


def constrain(filled, missing, *, extrapolate: int | None = None, long: int | None = None,
              names=None, pairs: RigidPairs | None = None,
              donors: tuple[np.ndarray, np.ndarray] | None = None, segments=None,
              spatial: bool = False, anchored: np.ndarray | None = None, limits=None
              ) -> tuple[np.ndarray, ConstraintReport]:
    """Apply the constraints to a method's fill.

    Parameters
    ----------
    filled : array (T, J, D)
        Observed samples plus the method's fill (NaN where it left a sample unfilled).
    missing : bool array (T, J)
        The samples that were missing (True) and may be changed.
    extrapolate : int, optional
        Frames a gap touching a trial end may be extrapolated without rigid donors (None: no limit).
    long : int, optional
        Gaps longer than this many frames filled without rigid donors get a warning.
    names : list of str, optional
        Marker names for the warnings.
    pairs : RigidPairs, optional
        Precomputed rigidity (default: found from the observed samples).
    donors : (array (T, J, D), bool array (T, J)), optional
        Precomputed :func:`rigid_donors` of the same observed samples (they do not depend on the
        fill: ``auto`` constrains every candidate's fill with one).
    segments : optional
        The segments the rigid donors come from (see :func:`rigid_donors`).
    spatial : bool
        The fill comes from a method that places a marker from the markers seen in the same
        frame (``auto``, the PMA family, Gløersen PCA): a trial-end sample in a frame with at least
        ``SPATIAL_MIN`` observed markers is not an extrapolation in time, and the
        ``extrapolate`` limit does not cut it (the fill's error estimate judges it instead).
    anchored : bool array (T, J), optional
        Filled samples the soft distances (step 5) hold still, as they hold observed ones:
        ``auto``'s fills from segment-mates, which went through step 5 as their candidate's fill
        already; a second pass moved them towards partners filled by less exact models (on the
        samples gapfill's rigid-body fill reaches: capture0002's mask on HDM_bd 0.84 -> 1.42 x
        gapfill's RMSE).
    limits : optional
        Precomputed :func:`observed_limits` of the same observed samples (the step limit and the
        capture volume; ``auto``'s candidates share them).
    """
    F = np.array(filled, dtype=np.float64)
    missing = np.asarray(missing, dtype=bool)
    observed = ~missing & _finite(F)
    report = ConstraintReport()
    if not missing.any() or not observed.any():
        return F, report
    done = np.zeros_like(missing)
    if F.shape[2] == 3:             # 2-D keypoints are projections: no rigid segments to keep
        if pairs is None:
            pairs = rigid_pairs(np.where(observed[..., None], F, np.nan), observed)
        R, done = donors if donors is not None else rigid_donors(F, observed, pairs, segments,
                                                                 names)
        done = done & missing
        np.copyto(F, R, where=done[..., None])
        del R                           # long recordings: a full-length copy fewer from here
    report.rigid, report.rigid_done = int(done.sum()), done
    free = missing & ~done
    if long is not None:
        report.long_gaps = [(j, a, b) for j, a, b in gap_runs(free) if b - a > long
                            and observed[:, j].any()]
    support = observed.sum(axis=1) >= SPATIAL_MIN if spatial else np.zeros(len(F), dtype=bool)
    dropped = _limit_extrapolation(F, free, extrapolate, report, support)
    _interpolate_blackouts(F, observed, free, report)
    # samples the limit dropped that the blackout interpolation filled again are not left NaN
    ok = _finite(F)
    report.unfilled_extrapolation = int((dropped & ~ok).sum())
    free &= ok
    _blend_edges(F, free, ok=ok)
    if F.shape[2] == 3:
        _soft_distances(F, free if anchored is None else free & ~anchored, pairs)
    report.step_limit, bounds = limits if limits is not None else observed_limits(F, observed)
    report.end_step_limit = report.step_limit * END_STEP_FACTOR / STEP_FACTOR
    _limit_steps(F, missing, report.step_limit, report, report.end_step_limit)
    _clamp_to_volume(F, bounds, missing, report)
    np.copyto(F, np.asarray(filled, dtype=np.float64), where=observed[..., None])
    _warn(report, names)
    return F, report


def rigid_donors(filled, observed: np.ndarray, pairs: RigidPairs | None = None, segments=None,
                 names=None) -> tuple[np.ndarray, np.ndarray]:
    """Step 1's rigid-body fill from the ``observed`` samples of ``filled`` (T, J, 3): the fill
    (NaN where no donors) and the (T, J) samples it fills. The donors are segment-mates
    (:func:`torchfill.solvers.rigid.rigid_fill`): ``segments`` as ``fill()`` resolved them (name
    -> marker indices), else the name tables when ``names`` fit them, else found from the data."""
    X = np.asarray(filled, dtype=np.float64)   # only its observed samples are read: no copy
    if segments is None:
        segments = "auto" if names is not None else "data"
    R, done = rigid_fill(X, observed, pairs, segments, names)
    return R.numpy(), done.numpy()


def _finite(F: np.ndarray) -> np.ndarray:
    """``np.isfinite(F).all(axis=2)``, a coordinate at a time (a tenth of the time: numpy's
    reduce over a last axis of 3 is slow)."""
    ok = np.isfinite(F[..., 0])
    for c in range(1, F.shape[2]):
        ok &= np.isfinite(F[..., c])
    return ok


def _runs(mask: np.ndarray, T: int):
    for j, a, b in zip(*(x.tolist() for x in _gaps(mask))):
        yield j, a, b, a == 0, b == T


def _gaps(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`torchfill.metrics.gap_runs` of ``mask`` (T, J) as arrays: each run's marker,
    start and stop (exclusive), markers in order, without a loop over the markers."""
    edge = np.zeros((mask.shape[1], mask.shape[0] + 2), dtype=np.int8)
    edge[:, 1:-1] = mask.T
    edge = np.diff(edge, axis=1)
    j, a = np.nonzero(edge == 1)
    return j, a, np.nonzero(edge == -1)[1]


def _limit_extrapolation(F, free, extrapolate, report, support) -> np.ndarray:
    """Keep at most ``extrapolate`` frames of a trial-end gap next to its observed edge, besides
    the frames with spatial ``support`` (T,); returns the (T, J) samples set to NaN."""
    T = F.shape[0]
    dropped = np.zeros(free.shape, dtype=bool)
    for j, a, b, at_start, at_end in _runs(free, T):
        if not (at_start or at_end) or (at_start and at_end):
            continue
        report.extrapolated_gaps.append((j, a, b))
        filled = np.isfinite(F[a:b, j]).all(axis=1)
        report.spatial_samples += int((filled & support[a:b]).sum())
        report.time_samples += int((filled & ~support[a:b]).sum())
        if extrapolate is None or b - a <= extrapolate:
            continue
        drop = np.arange(a, b - extrapolate) if at_start else np.arange(a + extrapolate, b)
        drop = drop[~support[drop] & filled[drop - a]]
        report.time_samples -= int(drop.size)
        F[drop, j] = np.nan
        dropped[drop, j] = True
    return dropped


def _interpolate_blackouts(F, observed, free, report) -> None:
    """Frames without any observed marker: interpolate the fill in time across them."""
    black = ~observed.any(axis=1)
    report.blackout_frames = int(black.sum())
    if not black.any():
        return
    t = np.arange(F.shape[0])
    for j in np.flatnonzero(free[black].any(axis=0)):
        known = ~black & np.isfinite(F[:, j]).all(axis=1)
        if known.sum() < 2:
            F[black, j] = np.nan
            continue
        inside = black & (t > t[known][0]) & (t < t[known][-1])
        for c in range(F.shape[2]):
            F[inside, j, c] = np.interp(t[inside], t[known], F[known, j, c])
        F[black & ~inside, j] = np.nan


def _blend_edges(F, free, held=None, ok=None) -> None:
    """Offset each gap's fill so that it continues the trajectory at both edges (blended).
    ``held`` (T, J): only an edge beside these samples moves the fill; beside another finite
    sample the offset is zero there (see :func:`meet_kept`). ``ok``: ``_finite(F)`` if known."""
    T = F.shape[0]
    ok = _finite(F) if ok is None else ok
    for j, a, b, _, _ in _runs(free, T):
        L = b - a
        d0 = _edge_offset(F, ok, j, a, side=-1)
        d1 = _edge_offset(F, ok, j, b - 1, side=+1)
        if held is not None:
            d0 = d0 if d0 is None or held[a - 1, j] else np.zeros(F.shape[2])
            d1 = d1 if d1 is None or held[b, j] else np.zeros(F.shape[2])
        if d0 is None and d1 is None:
            continue
        if d0 is None or d1 is None:                   # held at one edge: the offset fades
            fade = np.clip(1.0 - np.arange(L) / min(L, END_FADE), 0.0, 1.0)[:, None]
            F[a:b, j] += fade * d0 if d1 is None else fade[::-1] * d1
            continue
        s = np.full(1, 0.5) if L == 1 else np.arange(L) * (1.0 / (L - 1))   # np.linspace(0,
        s[-1] = 1.0 if L > 1 else 0.5                       # 1, L)'s bits, without its cost
        F[a:b, j] += (1 - s[:, None]) * d0 + s[:, None] * d1


def meet_kept(F: np.ndarray, fill: np.ndarray, kept: np.ndarray) -> None:
    """Offset each run of ``fill`` samples (T, J) of ``F`` (T, J, D, in place) that borders an
    earlier fill kept as it was (``kept``), so that it continues that kept trajectory as step 4
    continues an observed one; its other edge stays where it is. A second fill treats the
    earlier fills as gaps and puts them back after (``fill()`` on a filled recording): the new
    fill beside them otherwise stepped to them (numediart_03_rolling's LR_FM5, whose file marks
    two frames as filled before a trial-end gap: 35 mm in one frame, observed steps 1 mm)."""
    _blend_edges(F, fill & _finite(F), held=kept)


def _edge_offset(F, ok, j, t, side: int):
    """Offset that moves the fill at ``t`` onto the trajectory continued from ``t + side``."""
    e = t + side
    if e < 0 or e >= F.shape[0] or not ok[e, j]:
        return None
    e2 = e + side
    v = F[e, j] - F[e2, j] if 0 <= e2 < F.shape[0] and ok[e2, j] else 0.0
    return F[e, j] + v - F[t, j]


def _soft_distances(F, free, pairs: RigidPairs) -> None:
    """Move free filled samples towards their rigid partners' distances (Jacobi projection).
    Frames are independent: only those with a free pair member are projected, a block at a time
    (memory bounded for any length)."""
    rigid = pairs.rigid & ~pairs.duplicate
    band = SOFT_BAND * pairs.spread
    if pairs.wide is not None:      # pairs whose observed distances stay near that band
        floor = pairs.tol * pairs.scale     # a still pair's tiny MAD is not its motion's band
        with np.errstate(invalid="ignore"):
            rigid &= pairs.wide <= SOFT_WIDE * np.maximum(band, floor)
    j, k = pairs.j[rigid], pairs.k[rigid]
    if j.size == 0:
        return
    d0 = pairs.distance[rigid]
    band = band[rigid]
    cone = None if pairs.cone is None else (      # turned beyond SOFT_CONE: rigid in any pose
        pairs.direction[rigid], np.where(pairs.cone < SOFT_CONE, pairs.cone, np.inf)[rigid],
        pairs.cover[rigid])
    rows = np.flatnonzero((free[:, j] | free[:, k]).any(axis=1))
    size = max(1, SOFT_BLOCK // j.size)
    for a in range(0, rows.size, size):
        t = rows[a:a + size]
        G = F[t]
        _project_distances(G, free[t], j, k, d0, band, cone)
        F[t] = G


def _project_distances(F, free, j, k, d0, band, cone=None) -> None:
    """``SOFT_ITER`` Jacobi steps of the soft distances on the frames ``F`` (in place), over the
    (frame, pair) entries with a free member only (a few of the pairs in each frame), on the
    samples those entries touch only (gathered once, written back at the end); the moves are
    summed over the free samples among those only (the others never move).
    ``cone``: each pair's observed mean direction and angular range (see :func:`_unseen_turn`)."""
    D = F.shape[2]
    p, ia, ib, rows, cols, fa, fb, share_a, share_b, size = _entries(free, j, k)
    d0, band = d0[p], band[p]
    P = F[rows, cols]
    if cone is not None:
        band = band + d0 * (1 - cone[2][p]) * _unseen_turn(P.take(ia, 0) - P.take(ib, 0),
                                                            cone[0][p], cone[1][p])
    Q = np.ascontiguousarray(P.T)               # (D, samples): a coordinate a row
    moved = False
    for _ in range(SOFT_ITER):
        diff = Q.take(ia, 1) - Q.take(ib, 1)                               # (D, entries)
        n = diff[0] * diff[0]                   # norm_last's sum, a coordinate at a time
        for c in range(1, D):
            n = n + diff[c] * diff[c]
        n = np.sqrt(n)
        err = np.clip(n - d0, -band, band) - (n - d0)      # back inside the observed band
        use = np.isfinite(n) & (n > 0) & (err != 0)
        if not use.any():
            break
        on = np.flatnonzero(use)            # the others add 0.0 (NaN: see _poison)
        step = SOFT_WEIGHT * (err[on] / n[on]) * diff[:, on]
        C = _mean_moves(step, [(ia[on], share_a[on], fa[on]), (ib[on], share_b[on], fb[on])],
                        size)
        bad = np.flatnonzero(~np.isfinite(n))
        _poison(C, diff[:, bad], [ia[bad], ib[bad]], [fa[bad], fb[bad]])
        Q[:, :size] += C
        moved = True
    if moved:                       # a step adds 0.0 to the untouched samples: -0.0 becomes 0.0
        F += 0.0
        Q += 0.0
        F[rows, cols] = Q.T


def _entries(free: np.ndarray, j: np.ndarray, k: np.ndarray) -> tuple:
    """The (frame, pair) entries of :func:`_project_distances` for the ``free`` samples (T, J)
    of pairs ``j``, ``k``: each entry's pair ``p``, its samples' places ``ia``, ``ib`` among
    the samples touched (``rows``, ``cols``; the ``size`` free ones first), whether each is free
    (``fa``, ``fb``) and its share of a step. Kept for the same mask: ``auto``'s candidates
    share it."""
    def compute():
        T, J = free.shape
        t, p = np.nonzero(free[:, j] | free[:, k])
        a, b = j[p], k[p]
        ia, ib, rows, cols = _gathered(t * J + a, t * J + b, T, J, free)
        fa, fb = free[t, a], free[t, b]
        share_a, share_b = np.where(fb, 0.5, 1.0) * fa, np.where(fa, 0.5, 1.0) * fb
        return p, ia, ib, rows, cols, fa, fb, share_a, share_b, int(free[rows, cols].sum())
    return _KEPT_ENTRIES(compute, free, j, k)


_KEPT_ENTRIES = Memo(entries=4)


def _mean_moves(step: np.ndarray, sides: list, size: int) -> np.ndarray:
    """A Jacobi step's mean move (D, ``size``) of each of ``size`` samples: the entries' ``step``
    (D, n) added to their first samples, taken from their second ones, each ``(place, share,
    moves)`` of ``sides`` giving the entries' sample there, its share of the step and whether it
    moves; each sample's sum (in the entries' order) divided by the entries that move it. A
    sample that does not move would add 0.0 to its sum (see :func:`_sum_at`)."""
    C, count = np.empty((step.shape[0], size)), np.zeros(size, dtype=np.int64)
    for side, (place, share, mine) in enumerate(sides):
        at, weight, moves = place[mine], share[mine], step[:, mine]
        for c in range(step.shape[0]):
            if side == 0:
                C[c] = _sum_at(at, weight * moves[c], size)
            else:
                C[c] -= _sum_at(at, weight * moves[c], size)
        count += np.bincount(at, minlength=size)
    C /= np.maximum(count, 1)
    return C


def _poison(C: np.ndarray, diff: np.ndarray, places: list, mine: list) -> None:
    """A Jacobi step's mean moves ``C`` (D x samples, in place) with a sample's coordinate
    held where the difference ``diff`` (D x entries) of an entry without a finite distance is
    not finite there (its zero step times that NaN made the sum NaN, then 0): ``places`` the
    entries' samples on each side that move (``mine``); any other NaN or infinity as
    ``np.nan_to_num`` makes it."""
    if diff.size:
        held = np.zeros(C.shape[::-1], dtype=bool)
        for place, m in zip(places, mine):
            np.logical_or.at(held, place[m], ~np.isfinite(diff[:, m].T))
        C[held.T] = 0.0
    if not np.isfinite(C).all():
        np.nan_to_num(C, copy=False)


def _gathered(sa: np.ndarray, sb: np.ndarray, T: int, J: int, first: np.ndarray):
    """Each entry's two samples ``sa``, ``sb`` (flat indices into (T, J)) as places ``ia``, ``ib``
    among the samples touched, each once (their ``rows``, ``cols``): those of ``first`` (T, J)
    first, then the others, each part sorted (``np.unique(..., return_inverse=True)`` of the
    two parts), by a table of the (T, J) samples."""
    hit = np.zeros(T * J, dtype=np.int8)
    hit[sa] = 1
    hit[sb] = 1
    hit[hit.view(bool) & first.ravel()] = 2
    touched = np.concatenate([np.flatnonzero(hit == 2), np.flatnonzero(hit == 1)])
    place = np.empty(T * J, dtype=np.int64)
    place[touched] = np.arange(touched.size)
    rows, cols = np.divmod(touched, J)
    return place[sa], place[sb], rows, cols


def _unseen_turn(diff: np.ndarray, direction: np.ndarray, cone: np.ndarray) -> np.ndarray:
    """Angle (radians) by which each pair's fill ``diff`` turns beyond the orientations its
    distance was observed over. A distance measured only while a joint between the markers was
    still is no evidence for other joint angles: the chord ``d0 x angle`` widens the band, in
    proportion to the share of frames the pair was not seen in (a pair seen still throughout is
    likely still in its gaps too; numediart_03_rolling's mask on hdm05_bd_05-01: an upper-arm
    marker seen only in a still 18 % of the trial held the whole arm to its distances)."""
    with np.errstate(all="ignore"):
        n = norm_last(diff)
        angle = np.arccos(np.clip(np.einsum("nd,nd->n", diff, direction) / n, -1.0, 1.0))
        return np.nan_to_num(np.maximum(angle - cone, 0.0))


def _sum_at(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """``out[index[i]] += values.flat[i]`` over a zero vector of ``size`` (NaN where a NaN was
    added), in the order of ``index``."""
    return np.bincount(index, weights=values.ravel(), minlength=size)


def _limit_steps(F, missing, limit: float, report, end_limit: float | None = None) -> None:
    """Shorten a gap's steps beyond ``limit`` (``end_limit`` where the fill is held at one edge
    only), keeping its observed (or filled) edges."""
    if not np.isfinite(limit):
        return
    end_limit = limit if end_limit is None else end_limit
    T = F.shape[0]
    fin = _finite(F)
    gaps, paths = [], []
    for j, a, b in _steep(F, *_gaps(missing & fin), fin, limit, end_limit):
        left, right = a > 0 and fin[a - 1, j], b < T and fin[b, j]
        gaps.append((j, a, b, bool(left), bool(right)))
        paths.append(F[a - left:b + right, j])
    both = [g[3] and g[4] for g in gaps]
    caps = 0.999 * np.array([limit if x else end_limit for x in both])
    for (j, a, b, left, right), path, steps in zip(
            gaps, paths, _shorten([np.diff(p, axis=0) for p in paths], caps, both)):
        start = path[-1] - steps.sum(axis=0) if not left and right else path[0]
        new = start + np.concatenate([np.zeros((1, F.shape[2])), np.cumsum(steps, axis=0)])
        F[a:b, j] = new[int(left):len(new) - int(right)]
        report.shortened_gaps += 1


def _steep(F, j, a, b, fin, limit: float, end_limit: float):
    """The gaps (``j``, ``a``, ``b`` arrays) of ``F``'s finite samples ``fin`` with a step longer
    than their limit, the steps of every gap's path (its finite edges, its samples) measured at
    once: ``limit`` where both edges are finite, ``end_limit`` where one is."""
    T = F.shape[0]
    left = (a > 0) & fin[np.maximum(a - 1, 0), j]
    right = (b < T) & fin[np.minimum(b, T - 1), j]
    lo, hi = a - left, b - 1 + right            # the steps t -> t + 1 for t in [lo, hi)
    n = hi - lo
    over = n > 0
    j, a, b, lo, n = j[over], a[over], b[over], lo[over], n[over]
    if j.size == 0:
        return []
    first = np.cumsum(n) - n
    t = np.arange(n.sum()) - np.repeat(first - lo, n)
    k = np.repeat(j, n)
    top = np.maximum.reduceat(norm_last(F[t + 1, k] - F[t, k]), first)
    cap = np.where(left & right, limit, end_limit)[over]
    steep = ~(top <= cap)
    return zip(j[steep].tolist(), a[steep].tolist(), b[steep].tolist())


def _shorten(steps: list, limit: np.ndarray, both: list, n_iter: int = 50) -> list:
    """Each gap's ``steps`` (L, D) shortened to at most its ``limit`` (rounds of scaling the
    long steps down, then, where ``both`` edges hold it, spreading the lost way over all its
    steps; their mean where ``n_iter`` rounds do not meet the limit), the gaps' rounds taken
    together (each gap's own arithmetic, its sums over its steps in order)."""
    if not steps:
        return []
    size = np.array([len(x) for x in steps])
    S = np.concatenate(steps)
    total = _gap_sums(S, size)
    both = np.array(both, dtype=bool)
    out = [None] * len(steps)
    live = np.arange(len(steps))                      # the gaps still shortening
    n = norm_last(S)[:, None]                         # each step's length, once a round
    for _ in range(n_iter):
        L, cap = size[live], limit[live]
        S = S * np.minimum(1.0, np.repeat(cap, L)[:, None] / np.where(n > 0, n, 1))
        spread = np.repeat(both[live], L)
        if spread.any():
            lost = (total[live] - _gap_sums(S, L)) / L[:, None]
            S[spread] = S[spread] + np.repeat(lost, L, axis=0)[spread]
        n = norm_last(S)[:, None]
        first = np.cumsum(L) - L
        done = np.maximum.reduceat(n[:, 0], first) <= cap * (1 + 1e-9)
        for i in np.flatnonzero(done):
            out[live[i]] = S[first[i]:first[i] + L[i]]
        keep = np.repeat(~done, L)
        S, n, live = S[keep], n[keep], live[~done]
        if live.size == 0:
            return out
    for g, row in zip(live, np.cumsum(size[live]) - size[live]):
        L = size[g]
        out[g] = np.repeat(total[g][None] / L, L, axis=0) if both[g] else S[row:row + L]
    return out


def _gap_sums(S: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Each gap's ``S.sum(axis=0)`` (its ``size`` rows of S in turn, (gaps, D)): the same
    bits, a sum from 0.0 in the rows' order per column."""
    gap = np.repeat(np.arange(size.size), size)
    return np.stack([np.bincount(gap, weights=S[:, c], minlength=size.size)
                     for c in range(S.shape[1])], axis=1)


def observed_limits(F, observed) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """The step limit and the capture volume of the ``observed`` samples of ``F``: kept for the
    same observed samples (``auto``'s candidates share them; 25 of 30 ms of a candidate's
    constraints on 3000 x 41 markers went to these)."""
    def compute():
        return (step_limit(F, observed, q=STEP_PERCENTILE, factor=STEP_FACTOR),
                volume(F, observed, VOLUME_MARGIN))
    return _KEPT_LIMITS(compute, F[observed], observed, STEP_PERCENTILE, STEP_FACTOR,
                        VOLUME_MARGIN)


_KEPT_LIMITS = Memo(entries=4)
#: The rigid pairs of :func:`constrain_candidates`'s observed samples: ``auto`` constrains a fit
#: that ran on in the background on its own, after the others of its round (docs/speed.md).
_KEPT_PAIRS = Memo(entries=4)


def _clamp_to_volume(F, bounds, missing, report) -> None:
    lo, hi = bounds
    sel = missing & _finite(F)
    inside = F[sel]
    clamped = np.clip(inside, lo, hi)
    report.clamped = int((clamped != inside).any(axis=1).sum())
    F[sel] = clamped


def _warn(report: ConstraintReport, names) -> None:
    def label(j):
        return names[j] if names is not None else str(j)
    if report.extrapolated_gaps:
        marks = sorted({label(j) for j, _, _ in report.extrapolated_gaps})
        text = (f"{len(report.extrapolated_gaps)} gap(s) touch a trial end without rigid donors "
                f"(markers: {', '.join(marks[:8])}{' ...' if len(marks) > 8 else ''}): "
                + (f"{report.spatial_samples} sample(s) filled from markers seen in the same "
                   "frame, " if report.spatial_samples else "")
                + f"{report.time_samples} extrapolated in time")
        if report.unfilled_extrapolation:
            text += f", {report.unfilled_extrapolation} beyond the extrapolation limit left NaN"
        warnings.warn(text, RiskyFillWarning, stacklevel=3)
    if report.long_gaps:
        marks = sorted({label(j) for j, _, _ in report.long_gaps})
        warnings.warn(f"{len(report.long_gaps)} long gap(s) filled without rigid donors (markers: "
                      f"{', '.join(marks[:8])}{' ...' if len(marks) > 8 else ''}): check them "
                      "(torchfill qc)", RiskyFillWarning, stacklevel=3)
    if report.blackout_frames:
        warnings.warn(f"{report.blackout_frames} frame(s) with no marker observed: interpolated in "
                      "time from the fill around them, not reconstructed", RiskyFillWarning,
                      stacklevel=3)


def constrain_candidates(fills: torch.Tensor, missing: torch.Tensor, segments=None
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """Several candidate fills of one recording through the post-step, as ``auto`` scores them.

    ``fills`` (C, T, J, D): each candidate's fill; ``missing`` (T, J): the samples each may change
    (no extrapolation limit); ``segments``: as :func:`constrain` takes them (default: found from
    the data). Returns the constrained fills (a candidate's own value where the post-step left
    NaN) and the (T, J) samples that rigid donors fill: those depend on the observed samples only,
    so the rigid pairs and donors are found once for all candidates (:func:`prepare_candidates`),
    and the candidates are constrained in threads (numpy lets go of the GIL for most of it).
    """
    from .runtime.threads import thread_map

    if fills.shape[0] == 0:
        return fills, torch.zeros_like(missing)
    one, donor = prepare_candidates(fills[0], missing, segments)
    done = list(thread_map(one, fills))
    return torch.stack(done), donor


def prepare_candidates(observed: torch.Tensor, missing: torch.Tensor, segments=None
                       ) -> tuple[Callable[[torch.Tensor], torch.Tensor], torch.Tensor]:
    """What :func:`constrain_candidates` shares between the candidates, made once from the
    samples of ``observed`` (T, J, D) outside ``missing`` (the rigid pairs and donors, the step
    limit and the volume): ``(one, donor)``, ``one(F)`` a candidate's fill ``F`` (T, J, D)
    through the post-step (its own value where that left NaN) and ``donor`` the (T, J) samples
    rigid donors fill. ``auto`` constrains each candidate as its fit ends."""
    miss = missing.cpu().numpy()
    pairs = donors = None
    X = torch.where(missing[..., None], float("nan"), observed).cpu().numpy()
    seen = ~miss & _finite(X)
    donor = torch.zeros_like(missing)
    if X.shape[-1] == 3:
        pairs = _KEPT_PAIRS(lambda: rigid_pairs(X, seen), X[seen], seen)
        donors = rigid_donors(X, seen, pairs, segments)
        if miss.any() and seen.any():               # as constrain() reports it
            donor = torch.as_tensor(donors[1] & miss, device=missing.device)
    limits = observed_limits(X, seen)           # the same observed samples in every fill
    dtype = torch.empty(0, dtype=observed.dtype).numpy().dtype

    def one(F: torch.Tensor) -> torch.Tensor:
        own = F.cpu().numpy()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            G, _ = constrain(own, miss, pairs=pairs, donors=donors, segments=segments,
                             limits=limits)
        G = G.astype(dtype, copy=False)
        np.copyto(G, own, where=~np.isfinite(G))    # the candidate's own value where left NaN
        return torch.from_numpy(G).to(F.device)
    return one, donor


@dataclass(frozen=True)
class CandidatePost:
    """``auto``'s ``post`` fit data, as ``fill()`` passes it: :func:`constrain_candidates` with
    the recording's ``segments``, and :meth:`prepare` (:func:`prepare_candidates`) to constrain
    each candidate as its fit ends."""

    segments: dict | None = None

    def __call__(self, fills: torch.Tensor, missing: torch.Tensor):
        return constrain_candidates(fills, missing, self.segments)

    def prepare(self, observed: torch.Tensor, missing: torch.Tensor):
        return prepare_candidates(observed, missing, self.segments)
