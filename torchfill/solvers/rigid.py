"""Rigid-body reconstruction from segment-mates (Kabsch), and the rigid pairs of the data.

A marker on a segment (head, pelvis, a thigh cluster plate, a foot) is best filled from the other
markers of its segment in the same frame: the segment's motion is a rotation and a translation,
which three observed markers determine. This is what Vicon Nexus' rigid-body fill, QTM's kinematic
fill, ``gapfill.recover_marker_rbt`` and Kinetics Toolkit's ``track_cluster`` do. Which markers
form a segment comes from :mod:`torchfill.segments` (marker-name tables, the data, or a user file).

**The fill** (:func:`segment_fill`) of marker ``j`` at a missing frame ``t``, for each segment of
``j`` with three or more mates observed at ``t``: the nearest frames before and after ``t`` in
which ``j`` and three or more of those mates were observed are the references; the weighted
least-squares rotation and translation taking the mates from a reference frame to frame ``t``
(Kabsch 1976; each mate weighted by how rigid its distance to ``j`` was while both were observed,
``1 / (spread^2 + floor^2)``, and down-weighted in a frame where its distances to the other
mates leave their observed band: a ghost or a swapped label in a mate's track) carries ``j``'s
position in the segment along. An interior gap blends the two edges' estimates linearly in time
(the local position drifts with skin and soft tissue: the blend carries that drift across the
gap); a trial end uses its one edge. The error estimate of
a sample is measured on observed frames only: carrying observed ``j`` over the same number of
frames between reference frames (a few lags, up to ``HOLDOUT_FRAMES`` frames each) gives the RMS
error as a function of reach, interpolated at the sample's reach. Where ``j`` belongs to several
segments (a knee marker: thigh and shank), each sample takes the segment with the smaller estimate
(a fit from three mates first); a segment that completes the name tables from the data
(:func:`torchfill.segments.completed`) only where no other segment fills the sample. Fewer than
three mates observed: inside a gap that the fill reaches elsewhere, the sample is carried from the
nearest known samples of ``j`` on both sides by the mates it shares with them (two: the smallest
rotation of their line; one: its shift; none: linear in time), so that the gap is one fill rather
than a rigid fill with another model's pieces in it (the ``rigid`` method; ``auto``'s partial
candidate and the rigid donors of :mod:`torchfill.constraints` leave such samples out). A gap with
two mates seen in every frame and none with three is carried so from its two observed edges (the
turn about the mates' line taken from each edge, blended across the gap), with its own error
estimate: the hold-out error of carrying ``j`` by those two mates alone; like the carries above,
these samples are the ``rigid`` method's alone. Elsewhere (one mate or none) the sample is left
NaN for other models.

**Rigid pairs** (:func:`rigid_pairs`) are the near-neighbour pairs whose distance is nearly
constant (robust spread ``<= tol x`` the body's size); :mod:`torchfill.constraints` keeps their
distances softly. Only each marker's nearest neighbours are measured, so the cost grows linearly
with the markers (a 6 890-point surface needs no ``J x J`` array).

References
----------
Kabsch, W. (1976). A solution for the best rotation to relate two sets of vectors.
Acta Crystallographica A 32(5), 922-923.
"""
from __future__ import annotations

import hashlib
import warnings
from collections.abc import Mapping

import numpy as np
import torch

from .. import segments as _segments
from ..metrics import norm_last
from ..runtime.cache import Memo
from .base import OneShotSolver, Param, register
from .interp import Pchip
from .rigid_batch import _carry_few, _drive, _Fit
from .rigid_holdout import HOLDOUT_FRAMES, HOLDOUT_LAGS, _curve, _lag_pairs, _two_mates
from .rigid_pairs import RigidPairs, _numpy, body_size, rigid_pairs

Tensor = torch.Tensor


def _carry(seen, j, M, w, src, dst, min_mates=3, shape=None, firm=False, valid=True):
    """Marker ``j`` carried from frames ``src`` to frames ``dst`` by its mates ``M`` (weights
    ``w``; a mate counts where it is observed in both frames; with ``shape``, a mate whose
    distances to the others are off their observed band in either frame is down-weighted there;
    with ``firm``, a frame pair needs three mates above ``FIRM`` there: see
    :mod:`.rigid_batch`). Returns the bool (n,) of the pairs with ``min_mates`` mates (and
    ``valid``) and the :class:`.rigid_batch._Fit` carry of those, for :func:`_carried`."""
    W = w[None] * _both(seen, M, src, dst)
    ok = ((W > 0).sum(axis=1) >= min_mates) & valid
    return ok, (j, M, W[ok], src[ok], dst[ok], shape, firm)


def _both(seen, M, src, dst) -> np.ndarray:
    """The bool (n, k): each mate of ``M`` observed in both frames ``src`` and ``dst``."""
    flat, J = seen.reshape(-1), seen.shape[1]          # a 1-D take: a fast gather
    return flat.take(src[:, None] * J + M) & flat.take(dst[:, None] * J + M)


def _carried(ok: np.ndarray, answer) -> tuple[np.ndarray, np.ndarray]:
    """The estimates (n, 3) of a :func:`_carry` from its answer (NaN where none) and the bool
    (n,) of those."""
    e, posed = answer
    rows = np.flatnonzero(ok)[posed]
    out = np.full((ok.size, 3), np.nan)
    out[rows] = e[posed]
    good = np.zeros(ok.size, dtype=bool)
    good[rows] = True
    return out, good


def _edges(seen, j, M, w, todo, refs, min_mates):
    """The nearest reference before and after each ``todo`` frame and whether ``j`` can be
    carried from it: the plan ``(todo, b, a, okb, oka, w, Sb, Sa)`` of :func:`_edge_fits` and
    :func:`_blend` (``Sb``, ``Sa``: :func:`_both` of each edge), and the reach of each frame (to
    the nearer used edge)."""
    pos = np.searchsorted(refs, todo)
    b = refs[np.clip(pos - 1, 0, refs.size - 1)]
    a = refs[np.clip(pos, 0, refs.size - 1)]
    Sb, Sa = _both(seen, M, b, todo), _both(seen, M, a, todo)
    okb, oka = (((w[None] * S > 0).sum(axis=1) >= min_mates) & v     # :func:`_carry`'s ok
                for S, v in ((Sb, pos > 0), (Sa, pos < refs.size)))
    reach = np.where(okb & oka, np.minimum(todo - b, a - todo), np.where(oka, a - todo, todo - b))
    return (todo, b, a, okb, oka, w, Sb, Sa), reach


def _edge_fits(seen, j, M, plan, rows, min_mates, shape):
    """The plan of an :func:`_edges` plan's frames ``rows`` and their two carries (from the
    reference before, from the one after): each row is its own fit, the same bits whatever
    the other rows."""
    todo, b, a, okb, oka, Sb, Sa = (p[rows] for p in plan[:5] + plan[6:])
    w = plan[5]                                         # :func:`_carry`'s carries of the edges
    return (todo, b, a, okb, oka, w), [(j, M, (w[None] * S)[ok], e[ok], todo[ok], shape, False)
                                       for e, ok, S in ((b, okb, Sb), (a, oka, Sa))]


def _blend(plan, answers) -> np.ndarray:
    """The estimates of an :func:`_edges` plan: its two carries blended linearly in time."""
    todo, b, a, okb, oka, _ = plan
    eb, ea = _carried(okb, answers[0])[0], _carried(oka, answers[1])[0]
    span = np.maximum(a - b, 1)
    s = np.where(okb & oka, (todo - b) / span, np.where(oka, 1.0, 0.0))[:, None]
    return (1 - s) * np.where(okb[:, None], eb, 0.0) + s * np.where(oka[:, None], ea, 0.0)


def _segment_estimate(X, seen, j, M, w, min_mates=3, shape=None):
    """Which missing frames of marker ``j`` the mates ``M`` estimate, and the error (3-D RMS) of
    each; the estimates themselves at the frames a bridge starts from (:func:`_bridge`) and at
    the bridged ones only: the rest waits for :func:`_estimates` at the frames this segment is
    chosen for (a marker in several segments keeps one segment's fill a sample). Returns
    ``(frames, (frames estimated so far, their estimates), error, bridged, plan)``, the plan
    for :func:`_estimates`.

    References are the frames with ``j`` and ``min_mates`` mates observed; a frame whose nearest
    references share fewer than ``min_mates`` observed mates with it is carried instead from the
    nearest frames where all of its observed mates (then all but the least rigid, ...) were seen
    with ``j``. The hold-out error curve's carries and the bridges' starts go in one request."""
    T = X.shape[0]
    use = seen[:, M] & (w > 0)
    enough = use.sum(axis=1) >= min_mates
    todo = np.flatnonzero(~seen[:, j] & enough)
    refs = np.flatnonzero(seen[:, j] & enough)
    use = use[todo]                 # while the tasks wait on each other: no (T, ...) arrays held
    del enough
    if refs.size == 0:
        none = np.zeros(0, np.int64)
        return none, (none, np.zeros((0, 3))), np.zeros(0), np.zeros(0, bool), None
    lags = errs = np.zeros(0)
    plan = None
    known = seen[:, j].copy()
    if todo.size:
        parts, source, good, reach = _three_mates(seen, j, M, w, todo, refs, use, min_mates)
        known[todo[good]] = True
    holes = _holes(known)
    if todo.size:
        plan = (parts, source, todo, min_mates, shape)
        starts = np.unique(np.r_[holes[1], holes[2]])           # the bridges' estimated ends
        starts = np.searchsorted(todo, starts[~seen[starts, j]])
        pieces, fits = _part_fits(seen, j, M, plan, starts)
        src, dst, tag = _lag_pairs(refs, float(reach[good].max()) if good.any() else 0.0)
        hold, fit = _carry(seen, j, M, w, src, dst, shape=shape, firm=True)
        answers = yield _Fit(fits + [fit])
    est = np.full((T, 3), np.nan)       # (T, ...) arrays made once the wave's fits are done
    err = np.full(T, np.nan)
    if todo.size:
        est[todo[starts]] = _part_estimates(pieces, answers, starts.size)
        x, kept = _carried(hold, answers[-1])
        lags, errs = _curve(src, dst, tag, np.where(kept, np.nansum(
            (x - X[dst, j]) ** 2, axis=1), 0.0), kept)
        r = np.interp(np.log(np.maximum(reach, 1)), np.log(lags), errs) if lags.size \
            else np.full(todo.size, np.nan)           # too few observed frames to measure
        err[todo[good]] = r[good]
    bridged = yield from _bridge(X, seen, j, M, w, est, err, holes, lambda reach: np.interp(
        np.log(np.maximum(reach, 1)), np.log(lags), errs) if lags.size else np.nan)
    made = np.isfinite(est).all(axis=1)
    at = np.flatnonzero(~seen[:, j] & (known | bridged) & (made | ~bridged))   # two coincident
    made = np.flatnonzero(made)                         # mates carry nothing: not estimated
    return at, (made, est[made]), err[at], bridged[at], plan


def _three_mates(seen, j, M, w, todo, refs, use, min_mates):
    """:func:`_edges` of the ``todo`` frames from ``refs``; a frame whose nearest references
    share too few mates with it from the nearest frames where all of its observed mates (then
    all but the least rigid, ...) were seen with ``j`` (``use``: those mates, one row per
    ``todo`` frame). Returns the parts ``(frames or None: all, plan)``, the part that estimates
    each frame (the last that covers it), which frames are estimated and their reach."""
    plan, reach = _edges(seen, j, M, w, todo, refs, min_mates)
    good = plan[3] | plan[4]
    parts = [(None, plan)]
    source = np.zeros(todo.size, dtype=np.int64)
    if not good.all():                                   # mates seen there, not at the edges
        left = np.flatnonzero(~good)
        codes = use[left] @ (1 << np.arange(M.size, dtype=np.int64))
        rank = np.argsort(-w, kind="stable")             # most rigid mates first
        for code in np.unique(codes):
            sel = left[codes == code]
            S = [i for i in rank if code >> i & 1]
            while len(S) >= min_mates:
                r = np.flatnonzero(seen[:, j] & seen[:, M[S]].all(axis=1))
                if r.size:
                    w_s = np.zeros_like(w)
                    w_s[S] = w[S]
                    p2, reach[sel] = _edges(seen, j, M, w_s, todo[sel], r, min_mates)
                    good[sel] = p2[3] | p2[4]
                    source[sel] = len(parts)
                    parts.append((sel, p2))
                    break
                S = S[:-1]
    return parts, source, good, reach


def _part_fits(seen, j, M, plan, rows):
    """The carries of the ``todo`` frames ``rows`` (indices) of a :func:`_segment_estimate`
    plan, each in the part that estimates it: the pieces ``(where in rows, plan)`` of
    :func:`_part_estimates` and their carries in order."""
    parts, source, _, min_mates, shape = plan
    pieces, fits = [], []
    for n, (sel, part) in enumerate(parts):
        at = np.flatnonzero(source[rows] == n)
        if at.size:
            sub, f = _edge_fits(seen, j, M, part, rows[at] if sel is None
                                else np.searchsorted(sel, rows[at]), min_mates, shape)
            pieces.append((at, sub))
            fits += f
    return pieces, fits


def _part_estimates(pieces, answers, n: int) -> np.ndarray:
    """The estimates (n, 3) of :func:`_part_fits` from the answers to its carries."""
    e = np.zeros((n, 3))
    for i, (at, sub) in enumerate(pieces):
        e[at] = _blend(sub, answers[2 * i:2 * i + 2])
    return e


def _estimates(seen, j, M, plan, frames):
    """The estimates (n, 3) of ``j`` at ``frames`` of a :func:`_segment_estimate` plan."""
    rows = np.searchsorted(plan[2], frames)
    pieces, fits = _part_fits(seen, j, M, plan, rows)
    answers = (yield _Fit(fits)) if fits else []
    return _part_estimates(pieces, answers, rows.size)


def _holes(known):
    """The frames ``t`` not ``known`` between two known ones, and the known frame before (``b``)
    and after (``a``) each."""
    T = known.size
    frame = np.arange(T)
    before = np.maximum.accumulate(np.where(known, frame, -1))
    after = np.minimum.accumulate(np.where(known, frame, T)[::-1])[::-1]
    t = np.flatnonzero(~known & (before >= 0) & (after < T))
    return t, before[t], after[t]


def _bridge(X, seen, j, M, w, est, err, holes, curve) -> np.ndarray:
    """Fill, in place, the frames of a gap of ``j`` that the rigid fill left out (fewer than three
    mates observed there) between two frames where ``j`` is known (observed or estimated), one of
    them estimated: ``j`` carried from each of the two by the mates observed in both
    (:func:`_carry_few`), blended linearly in time as :func:`_blend` does. Without it such a
    frame falls to another model while its neighbours keep the rigid fill, and the fill jumps
    there (walking_hybrid_1_4's R_SHANK_3: 32-55 mm where a mate's samples are the file's own
    earlier fill). A trial end is left as it is: carried from its one side, walking_hybrid_1_4's
    thigh and shank markers jumped 100-330 mm where they met the rest of the fill. The error adds
    in quadrature the anchors' larger estimate, the hold-out ``curve`` at the reach to the nearer
    anchor and the two sides' disagreement times the blend's weight on the farther side (the
    turn about the mates' line that two mates do not see). ``holes``: :func:`_holes` of the
    frames where ``j`` is observed or estimated (``est`` holds the estimates the bridges start
    from). Returns the bool (T,) of the frames filled here.

    A gap that the fill left out whole (both edges observed) is filled where two mates are seen
    in all of its frames, with its own error estimate (:func:`_two_mates`); like a bridge, such
    a fill is the ``rigid`` method's alone: not a donor, not ``auto``'s candidate (the turn about
    the mates' line is unseen; experiments/results/auto.md)."""
    T = est.shape[0]
    t, b, a = holes
    bridged = np.zeros(T, dtype=bool)
    if t.size == 0:
        return bridged
    use = seen[:, M] & (w > 0)
    whole = seen[b, j] & seen[a, j]                        # a gap the fill left out whole
    two = whole & ((use[b] & use[t]).sum(axis=1) >= 2) & ((use[a] & use[t]).sum(axis=1) >= 2)
    _, gap = np.unique(b[whole], return_inverse=True)
    lacks = np.bincount(gap.reshape(-1), weights=~two[whole], minlength=1) > 0
    two[whole] &= ~lacks[gap.reshape(-1)]                  # all of a whole gap's frames or none
    keep = ~whole | two
    t, b, a, two = t[keep], b[keep], a[keep], two[keep]
    if t.size == 0:
        return bridged
    sides = []
    for e in (b, a):
        x = np.where(seen[e, j][:, None], X[e, j], est[e])
        sides.append((yield from _carry_few(X[e[:, None], M], X[t[:, None], M], use[e] & use[t],
                                            x, w)))
    s = ((t - b) / (a - b))[:, None]
    est[t] = (1 - s) * sides[0] + s * sides[1]
    anchor = np.maximum(np.where(seen[b, j], 0.0, err[b]), np.where(seen[a, j], 0.0, err[a]))
    split = np.minimum(s, 1 - s)[:, 0] * norm_last(sides[1] - sides[0])     # the turn unseen
    reach = np.minimum(t - b, a - t)
    err[t] = np.sqrt(anchor ** 2 + curve(reach) ** 2 + split ** 2)
    if two.any():                                          # unmeasured: the bridge's error
        e2 = np.sqrt(_two_mates(X, seen, j, M, use[t[two]], reach[two]) ** 2 + split[two] ** 2)
        err[t[two]] = np.where(np.isfinite(e2), e2, err[t[two]])
    bridged[t] = True
    return bridged


def index_segments(segments, labels=None, X=None, observed=None) -> "dict[str, list[int]]":
    """``segment name -> marker indices``: ``segments`` as :func:`torchfill.segments.resolve`
    takes it, or already a mapping to integer indices (used as given)."""
    if isinstance(segments, Mapping) and all(
            all(isinstance(m, (int, np.integer)) for m in v) for v in segments.values()) \
            and not isinstance(segments, _segments.Segments):
        return {str(k): [int(m) for m in v] for k, v in segments.items()}
    J = None if X is None else np.shape(X)[1]
    labels = list(labels) if labels is not None else [str(i) for i in range(J or 0)]
    seg = _segments.resolve(segments, labels if labels else None,
                            None if X is None else _numpy(X), observed)
    return dict(seg.indices(labels))


def segment_fill(X, observed=None, segments=None, labels=None, *, min_mates: int = 3,
                 bridge: bool = False) -> tuple[np.ndarray, ...]:
    """Rigid-body reconstruction of every missing sample that has ``min_mates`` segment-mates
    observed in its frame (see the module docstring).

    Parameters
    ----------
    X : array or tensor (T, J, 3)
        Marker positions, NaN where missing.
    observed : bool (T, J), optional
        The observed samples (default: the finite ones); only these are read.
    segments : optional
        Anything :func:`torchfill.segments.resolve` takes (a :class:`~torchfill.segments.Segments`,
        a dict name -> labels, a YAML path, "names", "data", None: the name tables if they fit the
        ``labels``, else found from the data), or a dict name -> marker indices.
    labels : list of str, optional
        The marker labels (needed for segments given by name).
    bridge : bool
        Also carry a marker across the holes in its mates inside a gap (see :func:`_bridge`),
        and return the bool ``(T, J)`` of those samples fourth.

    Returns
    -------
    estimate : array (T, J, 3)
        The reconstruction at missing samples it supports, NaN elsewhere (observed samples too).
    std : array (T, J)
        Its estimated error (per coordinate, data units), NaN where no estimate.
    segment_of : int array (T, J)
        Index of the segment that supported each estimate, -1 elsewhere: into
        ``list(index_segments(segments, labels, X, observed))`` (the resolved segments' names).
    """
    X = np.asarray(_numpy(X), dtype=np.float64)
    seen = np.isfinite(X).all(axis=2) if observed is None else _numpy(observed).astype(bool)
    seen = seen & np.isfinite(X).all(axis=2)
    m, s = _frame_of(X, seen)
    Xc = X - m                      # in place from here: long recordings hold fewer full copies
    Xc /= s
    Xc[~seen] = np.nan
    np.round(Xc, KEY_DECIMALS, out=Xc)  # the key's values: what is computed depends on the key
    Xc += 0.0                           # alone, not on whose units filled the cache first
    segs = index_segments(segments, labels, Xc, seen)
    key = _fingerprint(Xc, seen, segs, min_mates) if Xc.nbytes <= CACHE_BYTES else None
    hit = _KEPT.keyed(key, lambda: _segment_fill(Xc, seen, segs, min_mates))
    del Xc
    est, std, seg_of, bridged = hit if key is None else (a.copy() for a in hit)  # kept: a copy
    est *= s                        # in place: long recordings hold fewer full-length copies
    est += m
    std *= s
    if not bridge:
        est[bridged] = np.nan
        std[bridged] = np.nan
        seg_of[bridged] = -1
    return (est, std, seg_of, bridged) if bridge else (est, std, seg_of)


#: :func:`segment_fill` keeps its last results for this many recordings and masks (each at most
#: ``CACHE_BYTES`` of positions): ``fill()`` asks for the same one up to three times -- ``auto``'s
#: ``rigid`` candidate, the post-step's rigid donors of every candidate and the final post-step,
#: on the hold-out mask and on the real gaps, each in its own units -- and it was 13 of the
#: default's 42 s on bench_long's 3000 frames.
CACHE_ENTRIES = 4
#: The positions, in units of the recording's spread (:func:`_frame_of`), are rounded to this
#: many decimals (0.01 micrometre or less on a body) before anything is computed from them, so
#: the same recording in the data's units and in a solver's normalized ones is one input and
#: one result, whichever came first (the rare one whose last bits cross a rounding step is
#: computed again in its own units, as deterministically).
KEY_DECIMALS = 8
CACHE_BYTES = 64 << 20
_KEPT = Memo(CACHE_ENTRIES, max_bytes=2 * CACHE_BYTES)     # the results: ~1.7x the positions


def clear_cache() -> None:
    """Forget :func:`segment_fill`'s kept results (benchmarks time the computation itself)."""
    _KEPT.clear()


def _frame_of(X: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-axis mean and one scale of the observed positions: the fill is computed in these
    units (a rigid fill commutes with a shift and a uniform scaling), so that the same recording
    in the data's units and in a solver's normalized ones is one cache entry."""
    P = X[seen]
    if P.size == 0:
        return np.zeros(X.shape[2]), 1.0
    m = P.mean(axis=0)
    s = float(np.sqrt(np.mean((P - m) ** 2)))
    return m, s if s > 0 else 1.0


def _fingerprint(Xc: np.ndarray, seen: np.ndarray, segs: dict, min_mates: int) -> bytes:
    """Cache key: the observed positions (rounded to ``KEY_DECIMALS``), the mask, the
    segments."""
    h = hashlib.blake2b(digest_size=20)
    h.update(np.asarray(seen.shape, np.int64).tobytes())
    h.update(np.packbits(seen).tobytes())
    h.update(Xc[seen].tobytes())
    h.update(repr((sorted(segs.items()), min_mates)).encode())
    return h.digest()


def _segment_fill(X: np.ndarray, seen: np.ndarray, segs: dict, min_mates: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`segment_fill` on positions ``X`` (NaN where not ``seen``) and resolved segments:
    each segment's frames and errors first, the choice per sample, then each segment's
    estimates at the samples it was chosen for."""
    T, J = X.shape[:2]
    seen = np.ascontiguousarray(seen)                   # its rows taken flat (:func:`_carry`)
    est = np.full((T, J, 3), np.nan)
    std = np.full((T, J), np.nan)
    seg_of = np.full((T, J), -1, dtype=np.int64)
    bridged = np.zeros((T, J), dtype=bool)
    members = {s: np.unique(np.asarray(m, dtype=np.int64)) for s, m in segs.items()}
    tasks = _tasks(X, seen, members, min_mates)    # (segment, marker, mates, weights, shape)
    first: dict = {}                    # segments with the same members: one estimate each
    for n, (_, j, M, *_) in enumerate(tasks):
        first.setdefault((j, M.tobytes()), n)
    runs = sorted(set(first.values()))
    sizes = [2 * (~seen[:, tasks[n][1]]).sum() + HOLDOUT_FRAMES * len(HOLDOUT_LAGS) for n in runs]
    done = dict(zip(runs, _drive([_segment_estimate(X, seen, *tasks[n][1:4], min_mates,
                                                    tasks[n][4]) for n in runs], X, sizes)))
    run_of = np.full((T, J), -1, dtype=np.int32)              # each sample's chosen run
    extra = np.array([s.startswith(_segments.COMPLETION) for s in members] + [False])
    for si, j, M, *_ in tasks:                              # in order: the same choice
        n = first[(j, M.tobytes())]
        at, _, r, b, _ = done[n]
        per_coord = r / np.sqrt(3.0)
        rank = np.fmin(per_coord, np.finfo(float).max)      # unmeasured (NaN): last
        now = seg_of[at, j]
        mine = np.where(now >= 0, np.fmin(std[at, j], np.finfo(float).max), np.inf)
        was = bridged[at, j]             # a segment's fit from three mates before any bridge
        better = (now < 0) | ((b == was) & (rank < mine)) | (was & ~b)
        if extra[si]:                    # a completion: where no other segment fills
            better &= (now < 0) | extra[now] | (was & ~b)
        at = at[better]
        std[at, j] = per_coord[better]
        seg_of[at, j] = si
        bridged[at, j] = b[better]
        run_of[at, j] = n
    _chosen(X, seen, tasks, done, run_of, est)
    return est, std, seg_of, bridged


def _chosen(X, seen, tasks: list, done: dict, run_of: np.ndarray, est: np.ndarray) -> None:
    """Into ``est``, each segment's estimates at the samples it was chosen for (``run_of``):
    those :func:`_segment_estimate` made, and the rest computed now (:func:`_estimates`)."""
    later, where = [], []
    for n, (at, (made, e), _, _, plan) in done.items():
        j, M = tasks[n][1], tasks[n][2]
        mine = at[run_of[at, j] == n]
        have = np.isin(mine, made)
        est[mine[have], j] = e[np.searchsorted(made, mine[have])]
        rest = mine[~have]
        if rest.size:
            later.append(_estimates(seen, j, M, plan, rest))
            where.append((rest, j))
    for (rest, j), e in zip(where, _drive(later, X, [2 * r.size for r, _ in where])):
        est[rest, j] = e


def _tasks(X, seen, members: dict, min_mates: int) -> list:
    """``(segment index, marker, mates, weights, shape)`` of each marker with missing samples in
    each segment of more than ``min_mates`` members: the mates weighted by how rigid their
    distance to the marker was, ``1 / (spread^2 + floor^2)``; ``shape``: the mates' median
    distances and bands (:func:`_shape`)."""
    need = (~seen).any(axis=0) & seen.any(axis=0)
    pairs = [np.stack([m[a], m[b]], 1) for m in members.values() if m.size > min_mates
             for a, b in [np.triu_indices(m.size, 1)]]
    if not pairs:
        return []
    uniq = np.unique(np.concatenate(pairs), axis=0)
    stats = _segments.pair_stats(X, seen, (uniq[:, 0], uniq[:, 1]), min_frames=3,
                                 orientation=False)
    tasks = []
    for si, m in enumerate(members.values()):
        if m.size <= min_mates:
            continue
        a, b = np.triu_indices(m.size, 1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            d = stats.distance[stats.lookup(m[a], m[b])]
            floor = 0.01 * np.median(d[~np.isnan(d)])              # nanmedian's value
        if not np.isfinite(floor) or floor <= 0:
            floor = 1e-9
        D0, spread = _shape(stats, m)
        for i in np.flatnonzero(need[m]):
            others = np.arange(m.size) != i
            w = np.where(np.isfinite(spread[i, others]),
                         1.0 / (spread[i, others] ** 2 + floor ** 2), 0.0)
            if (w > 0).sum() >= min_mates:
                inner = np.ix_(others, others)
                tasks.append((si, int(m[i]), m[others], w,
                              (D0[inner], 2.0 * spread[inner] + floor)))
    return tasks


def _shape(stats, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median distances (k, k) among the members ``m`` of a segment and their robust spreads, NaN
    where a pair was not measured. A marker's mates' bands (twice the spread, about the 95th
    percentile of a normal deviation, plus the floor; robust, so a ghost present in a fifth of
    the frames does not widen it) are what :func:`.rigid_batch._consistency` checks."""
    a, b = np.meshgrid(m, m, indexing="ij")
    idx = stats.lookup(a.ravel(), b.ravel()).reshape(a.shape)
    hit = (idx >= 0) & (a != b)
    return (np.where(hit, stats.distance[np.maximum(idx, 0)], np.nan),
            np.where(hit, stats.spread[np.maximum(idx, 0)], np.nan))


def rigid_fill(X, observed=None, pairs: RigidPairs | None = None, segments=None, labels=None,
               *, min_partners: int = 3) -> tuple[Tensor, Tensor]:
    """The rigid donors of :mod:`torchfill.constraints` and the QC: :func:`segment_fill` where its
    estimated error is within the rigidity tolerance (3-D RMS ``<= tol x scale``, about 3 mm on an
    adult body: truly rigid mates only), and a marker stored twice filled from its twin.

    A gap takes the donors at all of its samples that have them or at none (a donor edge inside
    a gap would pull the other method's fill there). The samples carried across a hole in the
    mates (``bridge`` of :func:`segment_fill`) are no donors: judged by their own larger
    estimate they would take the donors off the whole gap, and let through without it they
    changed the default's fill on the real gaps (2219 -> 2229 steps beyond a marker's own
    observed steps, one teleport more on numediart_03_rolling). Returns the fill (NaN where no
    donor; observed samples unchanged) and the bool ``(T, J)`` mask of the samples filled here,
    as tensors.
    """
    Xn = np.asarray(_numpy(X), dtype=np.float64)
    seen = np.isfinite(Xn).all(axis=2) if observed is None else _numpy(observed).astype(bool)
    pairs = pairs if pairs is not None else rigid_pairs(Xn, seen)
    est, std, _ = segment_fill(Xn, seen, segments if segments is not None else "data", labels,
                               min_mates=min_partners)
    done = np.isfinite(est).all(axis=2)
    good = done & (np.sqrt(3.0) * std <= pairs.tol * pairs.scale)
    gap = _gap_ids(~seen)                               # a gap's donors all or none: a fill
    bad = np.unique(gap[done & ~good])                  # edge inside a gap is worse than none
    done[np.isin(gap, bad[bad > 0])] = False
    out = est                       # segment_fill's own array: NaN at observed samples
    out[~done] = np.nan
    np.copyto(out, Xn, where=seen[..., None])
    _fill_duplicates(out, done, Xn, seen, pairs)
    return torch.from_numpy(out), torch.from_numpy(done)


def _gap_ids(missing: np.ndarray) -> np.ndarray:
    """Each missing sample's gap (T, J): a number of its own per run of missing frames of a
    marker (1, 2, ... column after column), 0 where observed."""
    m = missing.T
    start = m & ~np.c_[np.zeros((m.shape[0], 1), bool), m[:, :-1]]
    return (np.cumsum(start.reshape(-1)).reshape(m.shape) * m).T


def _fill_duplicates(out, done, X, seen, pairs: RigidPairs) -> None:
    """A marker stored twice: translate the twin by their median offset while both were seen."""
    for a, b in zip(pairs.j[pairs.duplicate], pairs.k[pairs.duplicate]):
        for j, k in ((a, b), (b, a)):
            both = seen[:, j] & seen[:, k]
            todo = np.flatnonzero(~seen[:, j] & seen[:, k] & ~done[:, j])
            if todo.size == 0 or not both.any():
                continue
            out[todo, j] = X[todo, k] + np.median(X[both, j] - X[both, k], axis=0)
            done[todo, j] = True


@register
class Rigid(OneShotSolver):
    """Rigid-body fill (weighted Kabsch) from >= 3 observed segment-mates, carried by the mates
    left across a hole in them inside a gap; PCHIP elsewhere, with a warning that counts those
    samples (``history_[-1]["fallback"]``).

    ``segments`` (fit data): a dict segment name -> marker indices (``fill()`` passes the
    segments it resolved from the labels, the data or the user's file); not given: found from
    the data.
    """

    name = "rigid"
    spatial = True
    fit_data = ("segments",)
    params = {
        "min_partners": Param(3, int, low=3, doc="observed segment-mates needed"),
        "fallback": Param(True, bool, doc="where fewer mates are seen: carried across the hole "
                                          "inside a gap, PCHIP elsewhere (False: leave NaN "
                                          "there, as auto's candidate does)"),
        "max_error": Param(None, float, low=0.0, allow_none=True,
                           doc="leave a sample to the other models (NaN, or PCHIP with fallback) "
                               "where its estimated 3-D error exceeds this share of the body's "
                               "size (median marker distance); None: no limit"),
    }

    def _initialize(self) -> None:
        self.require_3d("rigid bodies move in 3-D; a 2-D projection is not rigid")
        self.X_ = self.M_.clone()

    def step(self) -> dict[str, float]:
        seen = self.Omega_.all(dim=2)
        X = torch.where(seen[..., None], self.M_, torch.nan)
        segments = self.fit_data_.get("segments", "data")
        est, std, self.segment_of_, bridged = segment_fill(
            X.cpu().numpy(), seen.cpu().numpy(), segments, min_mates=self.min_partners,
            bridge=True)
        ok = np.isfinite(est).all(axis=2) & (self.fallback | ~bridged)
        if self.max_error is not None:                   # only where its own estimate is small
            size = body_size(X.cpu().numpy(), seen.cpu().numpy())
            ok &= np.sqrt(3.0) * np.nan_to_num(std, nan=np.inf) <= self.max_error * size
        est = np.where(ok[..., None], est, np.nan)
        std = np.where(ok, std, np.nan)
        done = torch.from_numpy(ok).to(seen.device)
        self.rigid_done_ = done
        self.std_ = torch.from_numpy(std).to(self.M_) * self.sigma_        # in the data's units
        R = torch.from_numpy(est).to(self.M_)
        if self.fallback:               # PCHIP of the markers it fills only (each column alone)
            base = self.M_.clone()
            cols = torch.nonzero((~seen & ~done).any(dim=0))[:, 0]
            if cols.numel():
                T = X.shape[0]
                base[:, cols] = Pchip()._interpolate(
                    self.M_[:, cols].reshape(T, -1),
                    self.Omega_[:, cols].reshape(T, -1)).reshape(T, cols.numel(), -1)
        else:
            base = torch.full_like(self.M_, float("nan"))
        self.X_ = torch.where(done[..., None], R, base)
        missing = int((~seen).sum())
        left = (~seen & ~done).sum(dim=0)
        fallback = int(left.sum())
        if fallback and self.fallback:                    # never silent: which, how many
            where = ", ".join(f"{j} ({int(left[j])})" for j in torch.nonzero(left)[:, 0].tolist())
            warnings.warn(f"rigid: {fallback} of {missing} missing samples have too few "
                          f"segment-mates observed for a rigid-body fill: filled by PCHIP; "
                          f"markers (samples): {where}", UserWarning, stacklevel=2)
        return {"delta": 0.0, "rigid_share": float(done.sum()) / max(missing, 1),
                "fallback": float(fallback)}

    def _estimate(self) -> Tensor:
        return self.X_
