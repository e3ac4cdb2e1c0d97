"""``auto``: per gap, the candidate methods that fill gaps of that kind best on THIS recording, and
an estimate of each filled sample's error.

How (observed data only, never the ground truth of the gaps):

1. One hold-out ``V`` of observed samples shaped like the recording's own gaps
   (:func:`~torchfill.solvers.holdout.shifted_gap_holdout`: same markers, lengths and
   simultaneity, moved in time) plus the trial-end gaps mirrored onto the other trial end
   (:func:`~torchfill.solvers.holdout.mirrored_edge_holdout`), so extrapolation is scored on
   extrapolation.
   A second such hold-out (``draws=2``: another shift) is fitted and scored the same way and the
   errors of both are pooled: which shift one draw takes moved single cases by 20-30 % and more
   (the 19-case mask suite's mean RMSE at seed 0 / 1: one draw 11.57 / 13.60 mm, two 10.95 /
   11.55; cases above 1.25x their best single method 7 / 7 against 3 / 4). A recording with
   few gaps holds out few per draw, and which ones then decides the weights (cmu_85_02 with
   ten 50-frame gaps: 10.8 / 21.9 / 6.5 / 7.1 mm at seeds 0-3): draws go on, up to
   ``MAX_DRAWS``, until ``min_gaps`` held-out gaps are pooled (with four draws 10.8 / 6.6 / 6.4 /
   8.0; the mask suite at seed 1 11.36 -> 10.60 mm, worst case 3.36x -> 1.53x its best single
   method, at 2 % more CPU time over the suite).
2. Every candidate fits once on the data with ``V`` hidden and is scored on ``V``. A candidate
   that fails on the recording (e.g. ``pca_train`` without enough complete frames, ``rigid`` or
   ``pma`` on 2-D keypoints) is dropped. Given a ``post`` step as fit data (``fill()`` passes its
   constraints post-step when they are on) each fill first goes through it, so candidates are
   scored on what fill() will return; held-out samples that rigid donors fill (the same for every
   candidate) do not count in the choice. ``rigid`` fills only where three segment-mates are
   seen and its own error estimate is small (``PARTIAL``); ``tucker_tnn`` runs only when long
   interior gaps hold a quarter of the missing samples (``INTERIOR``).
3. Each gap (real or held out) gets a kind: at a trial end or inside, its length (``<= 20``,
   ``<= 80``, longer frames), and whether it is fast (its frames move more than ``FAST`` times the
   recording's median frame motion, measured on the markers seen there). Per kind, the candidates'
   held-out mean squared errors give the weights of a weighted average (``combine="average"``:
   inverse-MSE weights over the candidates within ``keep_ratio`` of the best, the model averaging
   of Tits et al. 2018 with weights from held-out errors; ``"select"``: the best alone); then on
   each gap the candidates that stray from the others count less (:func:`consensus`). A kind
   seen in few held-out gaps leans on its parent (see :func:`kind_weights`). With training
   recordings (``cross=True``, the default), a trial-end kind's mean squared errors are the
   geometric mean of ``V``'s and those of the cross-trial hold-out (the recording's gap pattern
   laid whole onto a training recording, :meth:`Auto._cross_holdout`): a candidate must fill both
   well.
4. The candidates that carry weight on a real gap are refitted on every observed sample, and the
   real gaps get the weighted average of the refits, each reusing what its hold-out fit chose
   (:meth:`Solver.carry`: Tucker's eps schedule) (``refit=False``: of the hold-out fits, one
   fit per candidate; on scripts/eval_auto.py that raised the mean RMSE from 5.05 to 5.72 mm and
   the worst case from 1.4x to 4x the best single method).
5. The error estimate ``std_`` (T, J): a log-linear model of the held-out squared error of the
   combined fill on the sample's distance to the nearest observed frame, its gap's length,
   trial-end status, the share of markers missing in its frame, the candidates' disagreement there,
   the fill's departure from linear interpolation, the marker's observed speed, the gap's frame
   motion and whether rigid donors fill the sample; fitted on the held-out samples, scaled so that the mean ratio of squared error to
   estimated variance there is 1, and grown in proportion to the motion beyond the 90th percentile
   of the hold-out's motion (which the fit cannot see).
6. A long recording's later windows (:mod:`torchfill.windows`) take the first window's choice
   (:meth:`Auto.carry`, the ``choice`` parameter): the candidates with weight, their weights per
   gap kind, their own carries and the error model. Each window fits only those candidates,
   once, on its real gaps -- one round of fits instead of three or more -- and its gaps get their
   kinds from the window itself (kinds the first window did not hold out have their parents'
   weights, see :func:`kind_mse`). A window that would try other candidates (``tucker_tnn``
   where long interior gaps hold a quarter of its missing samples and did not in the first
   window, or the reverse) chooses for itself.

References
----------
Tits, Tilmanne & Dutoit, "Robust and automatic motion-capture data recovery using soft skeleton
constraints and model averaging", PLoS ONE 13(7): e0199744 (2018).
"""
from __future__ import annotations

import threading
import warnings
from collections.abc import Iterator

import torch

from .. import ops
from ..runtime.memory import trim_heap
from ..runtime.threads import thread_map
from .base import Param, Solver, available, get_solver, register
from .holdout import mirrored_edge_holdout, shifted_gap_holdout

Tensor = torch.Tensor

#: Candidates tried by default, in this order; names not registered (yet) are skipped: the
#: temporal interpolants for short gaps, the spatial models of Tits et al. 2018 (``li``,
#: ``lgrnn``, ``glr`` and their average ``pma``) and Gløersen PCA, which place a marker from the
#: markers seen in the same frame (real gaps sit mostly at trial ends, where nothing else works),
#: and ``tucker_tnn`` for long interior gaps and dense occlusion. ``rigid`` is left out when a
#: post-step runs (its rigid donors are that fill). ``svt``, ``cp`` and ``pca_train`` were never
#: the best single method on the real-gap-pattern suite and cost a third of the fits' time
#: (``cp`` won one still 80-frame window of the mask suite by 0.02 mm); pass ``candidates=`` to
#: try them.
DEFAULT_CANDIDATES = ("pchip", "spline", "rigid", "li", "lgrnn", "glr", "pma", "pca_gloersen",
                      "tucker_tnn")
#: Default candidates that only run when interior gaps longer than ``LENGTH_EDGES[0]`` frames
#: hold at least ``INTERIOR_SHARE`` of the missing samples: a low-rank model in time extrapolates
#: poorly at trial ends, where most real gaps are, and it is most of the fits' time (41 % of a
#: real-gap-pattern case's profile).
INTERIOR = ("tucker_tnn",)
INTERIOR_SHARE = 0.25
#: Candidates that fill only some samples (NaN elsewhere), with the parameters that make them so:
#: ``rigid`` where three segment-mates are seen and its own error estimate (measured on observed
#: frames) is within 5 % of the body's size (about 30 mm). At 1.5 % the default lost to gapfill's
#: rigid-body fill on gapfill's own samples of the real-gap-pattern suite (mean ratio 1.20, worst
#: 4.2: a foot marker rigid filled at 3.2 mm was left to pma at 25 mm); no limit lets a soft-tissue
#: segment carried far from its reference frames win the hold-out of a 100-frame window of 20
#: markers in a flip (cmu_85_02: 28 mm where pma gives 10.5; 11.1 mm at 5 %, 10.9 at 1.5 %). The
#: samples such a candidate fills form gap kinds of their own (see :func:`gap_kind`), in which it
#: competes with the others; elsewhere it has no weight.
PARTIAL = {"rigid": {"fallback": False, "max_error": 0.05}}
#: With training recordings (fit data ``training``: the subject's other trials), the candidates in
#: ``TWINS`` learn from their frames too (:mod:`torchfill.solvers.session`), under the name
#: ``NAME+session``; the ones in ``ALONE`` also stay in as they were, so that the hold-out can
#: still choose the recording's own evidence where another trial misleads (a different motion).
#: A twin's fill of a gap touching one trial end is shifted as a whole onto the trajectory
#: continued from the gap's observed edge (:func:`end_shift`): another trial places a marker
#: where that trial had it, an offset the post-step's edge fade (over 10 frames) leaves in the
#: rest of the gap. With training, a trial-end gap kind's weights also weigh the cross-trial
#: hold-out (:meth:`Auto._cross_holdout`, ``cross``).
#: ``pma`` and ``glr`` run only as their twins (``pma+session`` with ``pma`` beside it cost a third
#: of the session's extra time on scripts/bench_session.py; with ``pma`` and ``glr`` on the
#: recording too, the session suite's trial-end mean ratio went 0.876 -> 0.870 at 1.84x instead of
#: 1.33x the suite's fill time alone), ``lgrnn`` only on the recording (its twin cost as much and
#: carried weight on 2 of 10 trials there), ``li`` only as its twin (its training frames only
#: choose its reference markers and their distance ranges; with ``li`` on the recording too the
#: suite's trial-end mean ratio was 0.876 with 5 cases worse than 1.05x, worst 1.44x, at 1.33x the
#: fill time alone; without it 0.861, 5, 1.35x at 1.27x).
SESSION = "+session"
TWINS = ("li", "glr", "pma", "pca_gloersen")
ALONE = ("lgrnn", "pca_gloersen")
#: Relative time of a candidate's fit (others: 1), so that the longest start first when they run
#: side by side (:func:`torchfill.runtime.threads.thread_map`'s ``cost``): seconds at one thread on
#: bench_long's 3 000 frames x 41 markers (tucker_tnn 5.9, rigid 3.3, pma 2.7, lgrnn 0.8, glr 0.6,
#: li 0.5, pchip 0.2, spline 0.1, pca_gloersen 0.1); a ``+session`` twin as its method.
COST = {"tucker_tnn": 8.0, "rigid": 4.0, "pma": 4.0, "pchip": 0.3, "spline": 0.3,
        "pca_gloersen": 0.3}
#: Errors that drop a candidate for this recording instead of failing the fill.
FAILURES = (ValueError, RuntimeError, torch.linalg.LinAlgError)
#: A ``+session`` twin's place in the second hold-out draw: not fitted there, its errors NaN, so
#: its gap kinds' mean squared errors are those of the first draw alone. The twins fit the
#: training trials' frames too, most of a session's time: with them in the second draw a batch of
#: 10 trials with ``--session`` took 1.86x the batch without it, without them 1.13x
#: (scripts/bench_session.py, the trials cut to 200 frames in the pool then, so without the
#: cross-trial hold-out); the session suite's trial-end mean ratio moved 0.925 -> 0.914.
NOT_DRAWN = RuntimeError("not fitted in this draw")
#: What a fit's choice holds (:meth:`Auto.carry`, the ``choice`` parameter).
CHOICE_KEYS = frozenset({"tried", "names", "weights", "mse", "error_model", "carried", "scores"})
#: Most hold-out draws that ``min_gaps`` asks for.
MAX_DRAWS = 4
#: Gap-length bucket edges in frames (a gap's kind: trial end or not x length bucket).
LENGTH_EDGES = (20, 80)
#: A gap is "fast" when the frames it spans move this many times the recording's median frame
#: motion (squared step): real occlusions cluster in fast phases, which a time-shifted hold-out
#: mostly misses (ktk_tennis_serve_nan: real short gaps at 11x the median, held-out ones at 0.9x).
FAST = 3.0
#: A kind's held-out errors count as much as their number of held-out gaps against this many
#: gaps of its parent (all gaps at a trial end / inside, then all gaps, each among the samples
#: a partial candidate fills or among the others): see :func:`kind_mse`.
PRIOR_GAPS = 10.0
#: Window starts tried for the cross-trial hold-out (:func:`motion_match`), every this many frames.
MATCH_STRIDE = 10
#: Gap kinds without a partial candidate (see :func:`gap_kind`), and all of them: a sample a
#: partial candidate fills has the kind ``N_BASE`` higher.
N_BASE = 4 * (len(LENGTH_EDGES) + 1)
N_KINDS = 2 * N_BASE

def interior_share(Omega: Tensor) -> float:
    """Share of the missing samples (a sample: any coordinate of a marker in a frame) that lie in
    gaps longer than ``LENGTH_EDGES[0]`` frames touching neither trial end."""
    missing = ~Omega.reshape(Omega.shape[0], Omega.shape[1], -1).all(dim=2)
    n = int(missing.sum())
    if n == 0:
        return 0.0
    _, L, edge = run_geometry(missing)
    return float((missing & ~edge & (L > LENGTH_EDGES[0])).sum()) / n


def run_bounds(missing: Tensor) -> tuple[Tensor, Tensor]:
    """Per sample of the (T, J) mask: the last observed frame before it (-1: none) and the next
    observed frame after it (T: none)."""
    T = missing.shape[0]
    t = torch.arange(T, device=missing.device)[:, None].expand_as(missing)
    obs = ~missing
    prev = torch.cummax(torch.where(obs, t, -1), dim=0).values
    nxt = T - 1 - torch.cummax(torch.where(obs, T - 1 - t, -1).flip(0), dim=0).values.flip(0)
    return prev, torch.where(nxt > T - 1, torch.full_like(nxt, T), nxt)


def run_geometry(missing: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Per sample of the (T, J) ``missing`` mask: distance in frames to the nearest observed frame
    of its marker, the length of its gap, and whether its gap touches a trial end (0 / 0 / False
    where observed)."""
    T = missing.shape[0]
    t = torch.arange(T, device=missing.device)[:, None].expand_as(missing)
    prev, nxt = run_bounds(missing)
    edge = (prev < 0) | (nxt >= T)
    far = torch.full_like(t, 2 * T)
    d = torch.minimum(torch.where(prev >= 0, t - prev, far), torch.where(nxt < T, nxt - t, far))
    L = nxt - prev - 1
    return (torch.where(missing, d.clamp(max=T), 0), torch.where(missing, L, 0),
            edge & missing)


def gap_kind(L: Tensor, edge: Tensor, fast: Tensor) -> Tensor:
    """Kind index per sample: ``4 * length bucket + 2 * fast + trial end``."""
    bucket = torch.zeros_like(L)
    for e in LENGTH_EDGES:
        bucket = bucket + (L > e).to(L.dtype)
    return 4 * bucket + 2 * fast.to(L.dtype) + edge.to(L.dtype)


def kind_name(k: int) -> str:
    partial, k = divmod(k, N_BASE)
    length = (LENGTH_EDGES + ("inf",))[k // 4]
    return (f"{'end' if k % 2 else 'inner'}{',fast' if k // 2 % 2 else ''}<={length}"
            f"{',segment' if partial else ''}")


def gap_motion(missing: Tensor, Y: Tensor) -> Tensor:
    """Per sample of a gap: the mean over its gap's frames of the frame motion (mean squared step
    of the markers seen in both frames, ``Y`` (T, J, D)), over the recording's median frame motion;
    0 where observed."""
    T = missing.shape[0]
    both = ~missing[1:] & ~missing[:-1]
    step = torch.diff(Y, dim=0).pow(2).mean(dim=2)
    m = torch.where(both, step, 0.0).sum(dim=1) / both.sum(dim=1).clamp(min=1)
    has = both.any(dim=1)
    m = ops.interp_linear(m[:, None], has[:, None])[:, 0] if bool(has.any()) else m
    m = torch.cat([m, m[-1:]])
    m = m / m.median().clamp(min=1e-12)
    C = torch.cat([m.new_zeros(1), torch.cumsum(m, dim=0)])[:, None].expand(T + 1, missing.shape[1])
    prev, nxt = run_bounds(missing)
    total = C.gather(0, nxt) - C.gather(0, prev + 1)
    return torch.where(missing, total / (nxt - prev - 1).clamp(min=1), 0.0)


def motion_match(Y: Tensor, seen: Tensor, Z: Tensor, stride: int = MATCH_STRIDE
                 ) -> tuple[int, float]:
    """The start of the ``T``-frame window of ``Z`` (T_k, J, D; NaN: not observed) whose frame
    motion is nearest to ``Y``'s (T, J, D) on a log scale, starts every ``stride`` frames; and
    that mean squared log distance. A frame's motion: the mean squared one-frame step of the
    markers seen in both frames in ``Y`` (``seen`` (T, J)) and in the window; windows a block at
    a time (memory bounded)."""
    T = Y.shape[0]
    both = seen[1:] & seen[:-1]
    zs = torch.isfinite(Z).all(dim=-1)
    zboth = zs[1:] & zs[:-1]
    sy = torch.nan_to_num(torch.diff(Y, dim=0)).pow(2).mean(dim=2)
    sz = torch.nan_to_num(torch.diff(Z, dim=0)).pow(2).mean(dim=2)
    starts = torch.arange(0, Z.shape[0] - T + 1, stride, device=Y.device)
    block = max(1, 2 ** 22 // max(T * Y.shape[1], 1))
    costs = []
    for s in starts.split(block):
        rows = s[:, None] + torch.arange(T - 1, device=Y.device)          # (n, T-1)
        w = both & zboth[rows]
        n = w.sum(dim=2).clamp(min=1)
        my = torch.where(w, sy, 0.0).sum(dim=2) / n
        mz = torch.where(w, sz[rows], 0.0).sum(dim=2) / n
        ok = w.any(dim=2)
        eps = 1e-3 * torch.where(ok, my, torch.nan).nanmedian(dim=1, keepdim=True).values + 1e-12
        d = (torch.log(my + eps) - torch.log(mz + eps)).pow(2)
        costs.append(torch.where(ok, d, torch.nan).nanmean(dim=1))
    cost = torch.nan_to_num(torch.cat(costs), nan=torch.inf) if costs else Y.new_full((1,), torch.inf)
    k = int(cost.argmin())
    return (int(starts[k]), float(cost[k])) if costs else (0, float("inf"))


def end_shift(F: Tensor, missing: Tensor) -> Tensor:
    """``F`` (T, J, D) with each gap of ``missing`` (T, J) that touches one trial end shifted as a
    whole onto the observed trajectory continued one frame at its speed from the gap's other edge
    (a constant offset: a model trained on another trial places a marker off by where that trial
    had it)."""
    T = F.shape[0]
    F = F.clone()
    for j, a, b in ops.runs(missing):
        if (a == 0) == (b == T):
            continue
        e, e2, t = (a - 1, a - 2, a) if a > 0 else (b, b + 1, b - 1)
        v = F[e, j] - F[e2, j] if 0 <= e2 < T and not bool(missing[e2, j]) else 0.0
        F[a:b, j] += F[e, j] + v - F[t, j]
    return F


def kind_weights(err2: Tensor, kinds: Tensor, gap_ids: Tensor, n_kinds: int, *, combine: str,
                 keep_ratio: float, prior: float = PRIOR_GAPS,
                 allowed: Tensor | None = None, partial_from: int | None = None) -> Tensor:
    """Candidate weights per kind, (n_kinds, C), from held-out squared errors ``err2`` (C, N) of
    samples of kind ``kinds`` (N,) that belong to the held-out gaps ``gap_ids`` (N,); a candidate
    takes part in kind ``k`` only where ``allowed[k, c]`` (default: everywhere). The mean squared
    errors per kind are :func:`kind_mse`'s."""
    M = kind_mse(err2, kinds, gap_ids, n_kinds, prior, partial_from)
    return mse_weights(M, combine=combine, keep_ratio=keep_ratio, allowed=allowed)


def kind_mse(err2: Tensor, kinds: Tensor, gap_ids: Tensor, n_kinds: int,
             prior: float = PRIOR_GAPS, partial_from: int | None = None) -> Tensor:
    """Per kind, each candidate's held-out mean squared error (n_kinds, C) (see
    :func:`kind_weights` for the arguments).

    A kind's mean squared errors are shrunk towards those of all gaps of its trial-end status,
    and those towards all gaps, each with the weight of ``prior`` gaps against the number of the
    kind's held-out gaps the candidate was scored on (samples of one gap are not independent; a
    ``+session`` twin skips the second draw, a partial candidate fills some): a kind seen in a few
    held-out gaps no longer picks a candidate that won there by chance (on the 19-case mask suite
    a kind decided by < 60 samples put PCHIP on 100-frame gaps: 2.5x the best method).

    With ``partial_from`` (even), the kinds from that index on are those a partial candidate
    fills, and their parents are taken among their own samples: the partial candidate is scored
    on those only, while a parent over all gaps held the others' errors where it does not fill,
    so it won its kinds on the shrinkage alone (walking_hybrid_1_2 laid on hdm05_bd: ``rigid``
    took every segment kind, 7.0 mm on those samples of the real gaps where ``pma`` errs 2.0).
    The other kinds keep the parents over all gaps (every candidate there fills every sample;
    parents without the segment samples cost ``cmu0201_m30_L100`` 8.1 -> 12.5 mm)."""
    gaps, slot = torch.unique(gap_ids, return_inverse=True)
    scored = (~torch.isnan(err2)).to(err2.dtype)

    def mse(sel: Tensor, parent: Tensor) -> Tensor:
        if not bool(sel.any()):
            return parent
        hit = torch.zeros(err2.shape[0], gaps.numel(), dtype=err2.dtype, device=err2.device)
        n = (hit.index_add_(1, slot[sel], scored[:, sel]) > 0).sum(dim=1).to(err2.dtype)
        own = err2[:, sel].nanmean(dim=1)      # n per candidate: the gaps it was scored on (a
        own = torch.where(n > 0, own, parent)  # twin fits one draw, a partial fills some)
        return (n * own + prior * parent) / (n + prior)

    every = err2.nanmean(dim=1)
    by_edge = [mse(kinds % 2 == e, every) for e in (0, 1)]
    out = [mse(kinds == k, by_edge[k % 2]) for k in range(n_kinds)]
    part = kinds >= (partial_from if partial_from is not None else n_kinds)
    if bool(part.any()):                       # the partial candidates' kinds: parents there
        top = err2[:, part].nanmean(dim=1)
        top = torch.where(torch.isnan(top), every, top)       # never scored there
        by_edge = [mse(part & (kinds % 2 == e), top) for e in (0, 1)]
        out[partial_from:] = [mse(kinds == k, by_edge[k % 2]) for k in range(partial_from, n_kinds)]
    return torch.stack(out)


def mse_weights(m: Tensor, *, combine: str, keep_ratio: float,
                allowed: Tensor | None = None) -> Tensor:
    """Weights (n_kinds, C) from mean squared errors ``m`` (n_kinds, C): per kind, inverse-MSE
    weights over the allowed candidates within ``keep_ratio`` of the best (``combine="select"``:
    the best alone)."""
    def weights(m: Tensor, ok: Tensor) -> Tensor:
        m = torch.where(torch.isnan(m) | ~ok, torch.inf, m)
        if combine == "select":
            w = torch.zeros_like(m)
            w[int(m.argmin())] = 1.0
            return w
        w = torch.where(m <= keep_ratio * m.min(), 1.0 / ops.clamp_tiny(m), 0.0)
        return w / w.sum()

    if allowed is None:
        allowed = torch.ones(m.shape, dtype=torch.bool, device=m.device)
    return torch.stack([weights(m[k], allowed[k]) for k in range(m.shape[0])])


def consensus(w: Tensor, fills: Tensor, missing: Tensor) -> Tensor:
    """The weights ``w`` (C, T, J; summing to 1 over the candidates) with, on each gap of
    ``missing`` (a marker's run) where three candidates or more carry weight, each candidate's
    divided by ``1 + dev / median dev``: ``dev`` its fill's RMS distance there from the weighted
    mean fill, the median over the candidates with weight. A gap kind's weights hold for every
    gap of that kind; a candidate that strays from the others on one gap is more often wrong
    there. With every candidate refitted on the session suite's 34 cases, a truth-chosen
    candidate per gap was 0.73x the default's error without training (0.91x the best one per
    case); this rule gave 0.99x. On the suites: mask suite mean 10.95 -> 10.62 mm (no case
    worse by 3 %), real-gap suite 22.76 -> 22.74, the session suite's trial-end cases alone
    49.5 -> 49.3, with the session 38.4 -> 37.5 mm. Dividing by ``1 + (dev / median)^2``
    gained more with the session but put one case 12 % above its weights without it."""
    F = torch.nan_to_num(fills)
    out = w.clone()
    for j, a, b in ops.runs(missing):
        ww = w[:, a:b, j]
        has = (ww > 0).to(F.dtype)
        on = has.sum(dim=1) > 0
        if int(on.sum()) < 3:
            continue
        mean = (ww[..., None] * F[:, a:b, j]).sum(dim=0)
        dev = ((((F[:, a:b, j] - mean) ** 2).sum(dim=-1) * has).sum(dim=1)
               / has.sum(dim=1).clamp(min=1)).sqrt()
        nw = ww / (1.0 + dev / dev[on].median().clamp(min=1e-12))[:, None]
        out[:, a:b, j] = nw / ops.clamp_tiny(nw.sum(dim=0, keepdim=True))
    return out


def gap_index(mask: Tensor) -> Tensor:
    """(T, J) index of each sample's run of ``mask`` (one per marker-gap), -1 outside."""
    idx = torch.full(mask.shape, -1, dtype=torch.long, device=mask.device)
    for i, (j, a, b) in enumerate(ops.runs(mask)):
        idx[a:b, j] = i
    return idx


def error_features(d: Tensor, L: Tensor, edge: Tensor, share: Tensor, spread2: Tensor,
                   bend2: Tensor, speed2: Tensor, motion: Tensor, donor: Tensor) -> Tensor:
    """Design matrix (..., 10) of the log-linear error model (see the module notes)."""
    dtype = spread2.dtype
    return torch.stack([torch.ones_like(spread2), torch.log(d.to(dtype)), torch.log(L.to(dtype)),
                        edge.to(dtype), torch.log(share.to(dtype)), torch.log(spread2 + 1e-8),
                        torch.log(bend2 + 1e-8), torch.log(speed2 + 1e-8),
                        torch.log(motion + 1e-3), donor.to(dtype)], dim=-1)


def fit_error_model(F: Tensor, e2: Tensor, ridge: float = 1e-3) -> tuple[Tensor, float]:
    """Least squares of ``log e2`` on the features ``F`` (ridge on the slopes), then the scale that
    makes the mean of ``e2`` over the predicted variance 1. Returns (coefficients, log scale)."""
    y = torch.log(e2 + 1e-10)
    R = ridge * torch.eye(F.shape[1], dtype=F.dtype, device=F.device) * F.shape[0]
    R[0, 0] = 0.0
    beta = torch.linalg.solve(F.T @ F + R, F.T @ y)
    log_scale = float(torch.log(torch.mean(e2 / torch.exp(F @ beta))))
    return beta, log_scale


@register
class Auto(Solver):
    """Per-gap choice and averaging of candidate methods from errors on gap-shaped hold-outs of
    the observed data, with an error estimate per filled sample (``std_``).

    Parameters
    ----------
    candidates : tuple of str, optional
        Registered method names to try (default ``DEFAULT_CANDIDATES``, those registered).
    candidate_params : dict, optional
        Hyperparameters per candidate, ``{name: {param: value}}``.
    combine : {"average", "select"}
        Per gap kind, inverse-MSE weighted average of the near-best candidates, or the best alone.
    keep_ratio : float
        ``average``: candidates whose held-out MSE is within this factor of the best take part.

    Attributes
    ----------
    std_ : Tensor (T, J)
        Estimated standard deviation of each coordinate's error at each filled sample, in the
        data's units; NaN where observed.
    scores_ : dict
        Held-out RMSE (normalized units, all held-out entries) per candidate that ran.
    weights_ : dict
        Per gap kind, the candidate weights used.
    cross_scores_ : dict
        With training data: RMSE (normalized units) per candidate on the cross-trial hold-out
        (see :meth:`_cross_holdout`); empty where it did not run.
    cross_window_ : tuple of int or None
        The training recording (its index) and the start frame of the window the cross-trial
        hold-out was laid onto.
    anchored_ : Tensor (T, J) of bool
        Missing samples whose fill is at least half a partial candidate's (``rigid``: rebuilt
        from segment-mates); ``fill()``'s soft distances hold them still.
    """

    name = "auto"
    iterative = False
    spatial = True
    fit_data = ("training", "post")
    params = {
        "max_iter": Param(1, int, low=1, doc="unused: one shot"),
        "candidates": Param(None, (tuple, list), allow_none=True,
                            doc="method names to try (None: DEFAULT_CANDIDATES that are registered)"),
        "candidate_params": Param(None, dict, allow_none=True,
                                  doc="hyperparameters per candidate, {name: {param: value}}"),
        "combine": Param("average", str, choices=("average", "select"),
                         doc="per gap kind: inverse-MSE average of the near-best candidates, or "
                             "the best alone (average: lower mean RMSE on scripts/eval_auto.py)"),
        "refit": Param(True, bool,
                       doc="refit the candidates that carry weight on all observed samples for the "
                           "real gaps (False: one fit per candidate, the hold-out fit fills them)"),
        "draws": Param(2, int, low=1,
                       doc="hold-out draws (shifts of the gap pattern) whose errors are pooled "
                           "for the weights, each a fit of every candidate (1: about a third "
                           "less time; the mask suite's mean 10.95 -> 11.57 mm at seed 0, "
                           "11.55 -> 13.60 at seed 1)"),
        "min_gaps": Param(40, int, low=0,
                          doc="draw again (up to MAX_DRAWS draws) until the pooled draws hold "
                              "out this many gaps: a recording with few gaps gets a thin "
                              "hold-out, whose draw decides the weights (0: exactly ``draws``)"),
        "cross": Param(True, bool,
                       doc="with training data: trial-end gap kinds scored by the geometric mean "
                           "of the recording's hold-out and the cross-trial hold-out's mean "
                           "squared errors (see _cross_holdout; on scripts/session_suite.py's "
                           "26 trial-end cases the mean ratio to the error alone 0.914 -> 0.876, "
                           "cases worse than 1.05x alone 8 -> 5; it needs a training recording "
                           "as long as the recording, and costs about one more round of fits)"),
        "choice": Param(None, dict, allow_none=True,
                        doc="an earlier window's choice of the same recording (its carry(): "
                            "candidates, weights per gap kind, error model): only the candidates "
                            "that carry weight are fitted, on the real gaps, with no hold-out "
                            "(a window that would try other candidates chooses for itself)"),
        "keep_ratio": Param(1.5, float, low=1.0,
                            doc="average: candidates within this factor of the best held-out MSE "
                                "(1.5: of 1.3/1.5/1.7/2 on scripts/eval_auto.py, 2 and 1.7 let a "
                                "low-rank fill into a near-still window where spline is 2.4x better)"),
    }

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        known = set(available())
        for name in self.candidates or ():
            base = name.removesuffix(SESSION) if isinstance(name, str) else name
            if not isinstance(name, str) or base not in known or base == self.name:
                raise ValueError(f"{self.name}: candidates expected registered method names "
                                 f"other than 'auto' (NAME{SESSION}: NAME with the training "
                                 f"data), found {name!r}")
        for name, p in (self.candidate_params or {}).items():
            if not isinstance(p, dict):
                raise ValueError(f"{self.name}: candidate_params expected {{name: dict}}, "
                                 f"found {name!r}: {p!r}")
        lacking = CHOICE_KEYS - set(self.choice or CHOICE_KEYS)
        if lacking:
            raise ValueError(f"{self.name}: choice expected an earlier fit's carry()['choice'], "
                             f"found a dict without {sorted(lacking)}")

    def candidate_names(self) -> list[str]:
        if self.candidates is not None:
            return list(self.candidates)
        names = [name for name in DEFAULT_CANDIDATES if name in available()]
        if hasattr(self, "Omega_") and interior_share(self.Omega_) < INTERIOR_SHARE:
            names = [name for name in names if name not in INTERIOR]
        if getattr(self, "fit_data_", {}).get("training") is not None:
            names = [twin for name in names for twin in self._session_twins(name)]
        return names

    @staticmethod
    def _session_twins(name: str) -> list[str]:
        """With training data: a default candidate in ``TWINS`` as ``NAME+session``, and as
        itself too when in ``ALONE``; any other as itself."""
        solver = get_solver(name)
        if name not in TWINS or not solver.spatial or "training" not in solver.fit_data:
            return [name]
        return [name, name + SESSION] if name in ALONE else [name + SESSION]

    # -- contract --------------------------------------------------------------------------
    def _initialize(self) -> None:
        self.X_ = self.interp_start()
        T, J = self.M_.shape[:2]
        self.std_ = torch.full((T, J), float("nan"), dtype=self.M_.dtype, device=self.M_.device)
        self.anchored_ = torch.zeros((T, J), dtype=torch.bool, device=self.M_.device)
        self.scores_: dict[str, float] = {}
        self.weights_: dict[str, dict[str, float]] = {}
        self.dropped_: dict[str, str] = {}
        self.carried_: dict[str, dict] = {}
        self.cross_scores_: dict[str, float] = {}
        self.cross_window_: tuple[int, int] | None = None
        self.error_model_: tuple | None = None

    def _estimate(self) -> Tensor:
        return self.X_

    def step(self) -> dict[str, float]:
        seen = self.Omega_.reshape(self.M_.shape[0], self.M_.shape[1], -1).all(dim=2)
        if bool(seen.all()):
            return {"delta": 0.0}
        if self.choice is not None and set(self.candidate_names()) == set(self.choice["tried"]):
            V = torch.zeros_like(seen)
            names, fills, donor, W, mse = self._chosen(~seen)
        else:
            names, fills, donor, W, mse, V = self._choose(seen)
        self._combine(names, fills, donor, W, mse, V, seen)
        return {"delta": 0.0, "candidates": float(len(names))}

    def _choose(self, seen: Tensor) -> tuple[list[str], Tensor, Tensor, Tensor, Tensor, Tensor]:
        """Steps 1-4 of the module notes: the hold-out ``V``, every candidate fitted with it
        hidden and scored per gap kind, the weights ``W`` (n_kinds, C), and (``refit``) the
        candidates with weight on a real gap refitted there. Returns the candidates' names, their
        fills (C, T, J, D: of ``V`` from the hold-out fits, of the real gaps from the refits),
        the (T, J) samples rigid donors fill, ``W``, each candidate's mean held-out squared
        error (C,) and ``V``."""
        V = self._holdout(seen)
        fit_missing = ~seen | V
        names, fills = self._run_candidates(fit_missing)
        fills, donor = self._constrain(fills, fit_missing)         # donor: rigid-donor samples
        Xt = self.M_.reshape(self.M_.shape[0], self.M_.shape[1], -1)
        kinds = self._kinds(names, fills, fit_missing, Xt)[-1]
        err2 = ((fills - Xt) ** 2).mean(dim=3)[:, V]                # (C, N), NaN: not filled
        decide = ~donor[V]                      # held-out samples the candidates fill themselves
        pooled = [(err2[:, decide], kinds[V][decide], gap_index(V)[V][decide])]
        while len(pooled) < self.draws or (len(pooled) < MAX_DRAWS and sum(
                int(p[2].unique().numel()) for p in pooled) < self.min_gaps):
            pooled.append(self._draw(names, seen, V))
        e_all = torch.cat([p[0] for p in pooled], dim=1)
        k_all = torch.cat([p[1] for p in pooled])
        g_all = torch.cat([p[2] + i * seen.numel() for i, p in enumerate(pooled)])   # apart
        allowed = torch.ones(N_KINDS, len(names), dtype=torch.bool, device=fills.device)
        allowed[:N_BASE, [c for c, n in enumerate(names) if n in PARTIAL]] = False
        cross = self._cross_holdout(names, seen) if self.cross else None
        if e_all.shape[1] == 0:                                     # nothing to choose on
            W = allowed / allowed.sum(dim=1, keepdim=True).to(fills.dtype)
        elif cross is not None:
            Mo = kind_mse(e_all, k_all, g_all, N_KINDS, partial_from=N_BASE)
            Mc = kind_mse(*cross, N_KINDS, partial_from=N_BASE)
            end = (torch.arange(N_KINDS, device=Mo.device) % 2 == 1)[:, None]
            M = torch.where(end & ~torch.isnan(Mc), (Mo * Mc).sqrt(), Mo)
            W = mse_weights(M, combine=self.combine, keep_ratio=self.keep_ratio, allowed=allowed)
        else:
            W = kind_weights(e_all, k_all, g_all, N_KINDS, combine=self.combine,
                             keep_ratio=self.keep_ratio, allowed=allowed, partial_from=N_BASE)
        if self.refit and bool(V.any()):
            w = W[kinds].permute(2, 0, 1)                           # (C, T, J)
            fills, real_donor = self._refit(names, fills, w, ~seen)
            donor = torch.where(V, donor, real_donor)
        self.scores_ = ({n: float(e.nanmean().sqrt()) for n, e in zip(names, err2)}
                        if err2.numel() else {})
        mse = (torch.nan_to_num(err2.nanmean(dim=1), nan=torch.inf) if err2.numel()
               else torch.ones(len(names), dtype=fills.dtype, device=fills.device))
        return names, fills, donor, W, mse, V

    def _combine(self, names: list[str], fills: Tensor, donor: Tensor, W: Tensor, mse: Tensor,
                 V: Tensor, seen: Tensor) -> None:
        """Step 5 of the module notes and the weighted average: the fills (C, T, J, D) of the
        real gaps and of ``V``, through the post-step, combined by the weights ``W`` of each
        sample's gap kind and :func:`consensus`; ``X_``, ``std_``, ``anchored_``, ``weights_``
        and ``choice_`` set. ``donor`` (T, J): the samples rigid donors fill; ``mse`` (C,): each
        candidate's held-out mean squared error (weights of the candidates' spread)."""
        fit_missing = ~seen | V
        Xt = self.M_.reshape(self.M_.shape[0], self.M_.shape[1], -1)
        d, L, edge, motion, kinds = self._kinds(names, fills, fit_missing, Xt)
        w = W[kinds].permute(2, 0, 1)                               # (C, T, J)
        w = torch.where(torch.isfinite(fills).all(dim=-1), w, 0.0)  # a partial fill's NaN
        w = w / ops.clamp_tiny(w.sum(dim=0, keepdim=True))
        for part in (~seen, V):                   # real and held-out gaps alike, each on its own
            w = consensus(w, fills, part)
        partial = torch.tensor([n in PARTIAL for n in names], device=w.device)
        self.anchored_ = ~seen & (w[partial].sum(dim=0) >= 0.5)     # mostly a segment fill
        mean = (w[..., None] * torch.nan_to_num(fills)).sum(dim=0)
        mean = self._join_holes(mean, fills, w, partial, fit_missing)
        fills = torch.where(torch.isfinite(fills), fills, mean)     # no say where it has none
        spread2 = self._spread2(fills, mean, mse)
        share = fit_missing.to(fills.dtype).mean(dim=1, keepdim=True).expand_as(spread2)
        lin = ops.interp_linear(Xt.reshape(Xt.shape[0], -1),                # V hidden too
                                (~fit_missing[..., None]).expand_as(Xt).reshape(Xt.shape[0], -1)
                                ).reshape(Xt.shape)
        bend2 = ((mean - lin) ** 2).mean(dim=2)                     # motion the fill adds
        step = torch.diff(Xt, dim=0).pow(2).mean(dim=2)
        both = ~fit_missing[1:] & ~fit_missing[:-1]
        speed2 = self._speed2(step, both).expand_as(spread2)
        self.weights_ = {kind_name(k): {n: round(float(x), 4) for n, x in zip(names, W[k]) if x > 0}
                         for k in range(N_KINDS)}
        segment = kinds >= N_BASE                   # a partial (segment) candidate fills it
        self._fit_std(V, seen, (d, L, edge, share, spread2, bend2, speed2, motion,
                                donor | segment),
                      ((mean - Xt) ** 2).mean(dim=2))
        est = torch.where(fit_missing[..., None], mean, Xt).reshape(self.M_.shape)
        self.X_ = torch.where(self.Omega_, self.M_, est)
        self.choice_ = {"tried": self.candidate_names(), "names": list(names),
                        "weights": W.tolist(), "mse": mse.tolist(),
                        "error_model": self.error_model_, "carried": dict(self.carried_),
                        "scores": dict(self.scores_)}

    def _chosen(self, gaps: Tensor) -> tuple[list[str], Tensor, Tensor, Tensor, Tensor]:
        """An earlier window's choice (``choice``, see :meth:`carry`): the candidates that carry
        weight in some gap kind, fitted on all observed samples (each with the carry of its
        earlier fit), through the post-step. Returns their names, fills (C, T, J, D), the
        samples rigid donors fill, their weights (n_kinds, C) and held-out mean squared errors
        (C,). A kind left without weight by a candidate that fails here takes the candidate
        with the smallest held-out error among those allowed there."""
        c = self.choice
        W = torch.tensor(c["weights"], dtype=self.M_.dtype, device=self.M_.device)
        mse = torch.tensor(c["mse"], dtype=self.M_.dtype, device=self.M_.device)
        self.carried_ = {k: dict(v) for k, v in c["carried"].items()}
        self.scores_ = dict(c["scores"])
        self.error_model_ = c["error_model"]
        use = [i for i in range(len(c["names"])) if bool((W[:, i] > 0).any())]
        outs = list(self._fit_all([c["names"][i] for i in use], gaps, "refit"))
        for i, out in zip(list(use), outs):
            if isinstance(out, Exception):
                self.dropped_[c["names"][i]] = str(out)
                use.remove(i)
        if not use:
            raise ValueError(f"{self.name}: every chosen candidate failed on this window: "
                             + "; ".join(f"{k}: {v}" for k, v in self.dropped_.items()))
        names = [c["names"][i] for i in use]
        W, mse = W[:, use], mse[use]
        for k in torch.nonzero(W.sum(dim=1) <= 0).flatten().tolist():
            ok = [n not in PARTIAL or k >= N_BASE for n in names]
            W[k, int(torch.where(torch.tensor(ok, device=W.device), mse, torch.inf).argmin())] = 1.0
        fitted = torch.stack([out for out in outs if not isinstance(out, Exception)])
        fills, donor = self._constrain(fitted, gaps)
        return names, fills, donor, W, mse

    def carry(self) -> dict:
        """The choice (candidates, weights per gap kind, error model): the next windows of the
        same recording fit only the candidates that carry weight, on their real gaps, with no
        hold-out (bench_long: see docs/speed.md)."""
        choice = self.choice if self.choice is not None else getattr(self, "choice_", None)
        return {"choice": choice} if choice is not None else {}

    def _kinds(self, names: list[str], fills: Tensor, missing: Tensor, Xt: Tensor
               ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """Per sample of ``missing`` (T, J) in ``Xt`` (T, J, D): its distance, gap length and
        trial end (:func:`run_geometry`), its gap's frame motion (:func:`gap_motion`) and its
        kind (:func:`gap_kind`, ``N_BASE`` higher where a partial candidate of ``fills`` fills
        it)."""
        d, L, edge = run_geometry(missing)
        motion = gap_motion(missing, Xt)
        kinds = gap_kind(L, edge, motion > FAST) + N_BASE * self._partial(names, fills)
        return d, L, edge, motion, kinds

    # -- pieces ----------------------------------------------------------------------------
    @staticmethod
    def _join_holes(mean: Tensor, fills: Tensor, w: Tensor, partial: Tensor,
                    missing: Tensor) -> Tensor:
        """``mean`` (T, J, D) with each hole in a partial candidate's fill (missing samples it
        leaves NaN between samples it fills: a mate hidden for some frames of the gap) shifted by
        the linear ramp between its offsets at the two sides from the samples beside it, so the
        other candidates' fill meets the segment fill instead of stepping to it (the time
        constraint of Tits et al. with the segment fill as the border). walking_hybrid_1_4's
        R_SHANK_3, R_SHANK_4 hidden at 316-332: 48.6 mm steps at both hole edges; 12 and 17 mm
        are left, the other candidates' own steps between a segment frame and the hole (starting
        the ramp on the segment fill continued at its speed removed those and cost the mask suite
        0.11 mm, cmu8502_m20_L100 11.9 -> 14.2). A hole that
        reaches an observed sample or a trial end is left as it is: ramped there too (to no
        offset, or the one side's held), the real-gap suite lost 0.13 mm on its mean
        (walking_hybrid_1_2 on hdm05_bd 8.24 -> 10.39 mm)."""
        seg = torch.zeros_like(missing)
        for c in torch.nonzero(partial).flatten().tolist():
            seg |= torch.isfinite(fills[c]).all(dim=-1)
        seg &= missing
        hole = missing & ~seg
        if not bool(seg.any()) or not bool(hole.any()):
            return mean
        T, J = missing.shape
        prev, nxt = run_bounds(hole)                      # the samples beside each hole sample
        j = torch.arange(J, device=mean.device).expand(T, J)
        p, n = prev.clamp(min=0), nxt.clamp(max=T - 1)
        others = torch.nan_to_num(fills)

        def offset(side: Tensor, inner: Tensor) -> Tensor:
            """Segment fill minus the hole's mix of the candidates, at the side sample."""
            g = (w[:, inner, j][..., None] * others[:, side, j]).sum(dim=0)
            return mean[side, j] - g
        inside = hole & (prev >= 0) & (nxt < T) & seg[p, j] & seg[n, j]
        if not bool(inside.any()):
            return mean
        D1, D2 = offset(p, (p + 1).clamp(max=T - 1)), offset(n, (n - 1).clamp(min=0))
        t = torch.arange(T, device=mean.device)[:, None].expand(T, J)
        s = ((t - prev) / (nxt - prev).clamp(min=1)).to(mean.dtype)[..., None]
        return torch.where(inside[..., None], mean + D1 + (D2 - D1) * s, mean)

    def _draw(self, names: list[str], seen: Tensor, V0: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Another hold-out draw, scored like the first (:meth:`_scored`; none when the draw
        repeats ``V0``). The ``+session`` twins are not fitted again (see ``NOT_DRAWN``)."""
        V = self._holdout(seen)
        if bool((V == V0).all()):
            empty = torch.empty(0, dtype=torch.long, device=V.device)
            return torch.empty(len(names), 0, dtype=self.M_.dtype, device=V.device), empty, empty
        fit_missing = ~seen | V
        Xt = self.M_.reshape(self.M_.shape[0], self.M_.shape[1], -1)
        run = [name for name in names if not name.endswith(SESSION)]
        fitted = dict(zip(run, self._fit_all(run, fit_missing, "draw")))
        outs = [fitted.get(name, NOT_DRAWN) for name in names]
        return self._scored(names, outs, fit_missing, Xt, V)[0]

    def _scored(self, names: list[str], outs, missing: Tensor, Xt: Tensor, V: Tensor
                ) -> tuple[tuple[Tensor, Tensor, Tensor], Tensor]:
        """The candidates' fits ``outs`` (in ``names``' order; an exception: the candidate
        failed) of ``Xt`` (T, J, D) with ``missing`` hidden, through the post-step and scored on
        the held-out samples ``V``: their squared errors (C, N), kinds (N,) and gap ids (N,) on
        the samples they fill themselves (not rigid donors); and the squared errors on all of
        ``V`` (C, N_V). A failed candidate's errors are NaN."""
        C = len(names)
        fills = torch.full((C, *Xt.shape), float("nan"), dtype=self.M_.dtype, device=V.device)
        for c, out in enumerate(outs):
            if not isinstance(out, Exception):
                fills[c] = out
        ok = [c for c in range(C) if bool(torch.isfinite(fills[c]).any())]
        fills[ok], donor = self._constrain(fills[ok], missing)
        kinds = self._kinds(names, fills, missing, Xt)[-1]
        err2 = ((fills - Xt) ** 2).mean(dim=3)[:, V]
        decide = ~donor[V]
        return (err2[:, decide], kinds[V][decide], gap_index(V)[V][decide]), err2

    @staticmethod
    def _partial(names: list[str], fills: Tensor) -> Tensor:
        """(T, J) samples a partial candidate (see ``PARTIAL``) fills, as 0/1."""
        got = torch.zeros(fills.shape[1:3], dtype=torch.long, device=fills.device)
        for c, name in enumerate(names):
            if name in PARTIAL:
                got = got | torch.isfinite(fills[c]).all(dim=-1).long()
        return got

    def _holdout(self, seen: Tensor) -> Tensor:
        """Held-out (T, J) samples: mirrored trial-end gaps, then the shifted gap pattern, each
        added to a marker only while it keeps half of its observed samples (and two at least).

        Part by part, not the union at once: a marker missing its last quarter got both a
        mirrored and a shifted copy of that gap, half its samples together, and dropped out of
        the hold-out altogether -- with every gapped marker so, nothing was held out and the
        candidates were averaged blindly (cmu_85_02, 400 frames, 5 markers missing the last 100:
        24.6 mm against pma's 8.8)."""
        Omega3 = seen[..., None]
        V = torch.zeros_like(seen)
        n_seen = seen.sum(dim=0)
        shifted = shifted_gap_holdout(Omega3, self.generator_)         # the generator's draw first
        for part in (mirrored_edge_holdout(Omega3), shifted):
            if part is None:
                continue
            W = V | part[..., 0]
            n = W.sum(dim=0)
            V = torch.where((n <= 0.5 * n_seen) & (n_seen - n >= 2), W, V)
        return V

    def _cross_holdout(self, names: list[str], seen: Tensor
                       ) -> tuple[Tensor, Tensor, Tensor] | None:
        """The cross-trial hold-out: the recording's own gaps, whole (all markers together, where
        they are), laid onto the ``T``-frame window of a training recording whose frame motion is
        nearest to the recording's (:func:`motion_match`; training recordings shorter than the
        recording are not used). Each candidate fills it (a ``+session`` twin with the
        recording's observed samples and the other training recordings as its training, the
        others on the window alone), through the post-step, and is scored on the training
        recording's observed samples under the laid gaps: which candidate fills exactly this gap
        pattern best on this subject, where the recording's own hold-out hides fewer markers at
        once and shorter stretches. Reads the recording's observed samples only.

        Returns the squared errors (C, N) (NaN: the candidate failed there), the samples' kinds
        and gap indices, without the samples rigid donors fill; None without training data, or
        where a marker would be seen nowhere in the window."""
        training = self.fit_data_.get("training")
        if not training:
            return None
        T, J = seen.shape
        Y = self.M_.reshape(T, J, -1)
        best = None
        for k, t in enumerate(training):
            if t.shape[0] < T:
                continue
            Z = (t.reshape(t.shape[0], J, -1) - self.mu_) / self.sigma_
            start, cost = motion_match(Y, seen, Z)
            if best is None or cost < best[0]:
                best = (cost, k, start, Z[start:start + T])
        if best is None:
            return None
        _, k, start, Z = best
        self.cross_window_ = (k, start)
        gaps = ~seen
        obs = torch.isfinite(Z).all(dim=-1)
        missing = gaps | ~obs
        if not bool((gaps & obs).any()) or not bool((~missing).any(dim=0).all()):
            return None
        Mx = torch.nan_to_num(Z).reshape(self.M_.shape)
        own = torch.where(seen.reshape(T, J, 1), self.M_.reshape(T, J, -1), float("nan"))
        train = [own.reshape(self.M_.shape)] + [(t - self.mu_) / self.sigma_
                                                 for i, t in enumerate(training) if i != k]
        outs = list(self._fit_all(names, missing, "cross", (Mx, train)))
        if all(isinstance(out, Exception) for out in outs):
            return None
        scored, err2 = self._scored(names, outs, missing, Mx.reshape(T, J, -1), gaps & obs)
        self.cross_scores_ = {nm: float(e.nanmean().sqrt()) for nm, e in zip(names, err2)}
        return scored

    def _fit_one(self, name: str, fit_missing: Tensor, case: tuple | None = None) -> Tensor:
        """Candidate ``name`` fitted with ``fit_missing`` (T, J) hidden; its fill (T, J, 3).
        ``case``: another recording to fit instead, ``(M, training)`` in the fit's units (the
        cross-trial hold-out, see :meth:`_cross_holdout`); nothing is carried from its fit."""
        T, J = fit_missing.shape
        M = self.M_ if case is None else case[0]
        X = torch.where(fit_missing[..., None], float("nan"), M.reshape(T, J, -1))
        method = name.removesuffix(SESSION)
        params = {"seed": self.seed, **PARTIAL.get(method, {}),
                  **(self.candidate_params or {}).get(method, {}),
                  **self.carried_.get(name, {})}
        solver = get_solver(method, **params)
        takes = [k for k in solver.fit_data              # a spatial default candidate learns
                 if k != "training" or name.endswith(SESSION)     # from training as +session
                 or not solver.spatial or name in (self.candidates or ())]
        data = {k: [(t - self.mu_) / self.sigma_ for t in v] for k, v in self.fit_data_.items()
                if k in takes}                            # training data in the fit's units
        if case is not None and "training" in data:
            data["training"] = case[1]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = solver.fit_transform(X, fit_missing, **data)
        if case is None and name not in self.carried_:   # the later fits reuse the first's
            self.carried_[name] = solver.carry()
        if name.endswith(SESSION):
            out = end_shift(out, fit_missing)
        done = torch.isfinite(out).all(dim=-1)
        if name in PARTIAL and bool(done[fit_missing].any()):
            return out.to(self.M_.dtype)                    # NaN where it does not fill
        if not bool(done.all()):
            raise ValueError("non-finite fill")
        return out.to(self.M_.dtype)

    def _attempt(self, name: str, fit_missing: Tensor, case: tuple | None = None
                 ) -> Tensor | Exception:
        """:meth:`_fit_one`, or the error that drops the candidate."""
        try:
            return self._fit_one(name, fit_missing, case)
        except FAILURES as err:
            return err
        finally:                        # the fit's solver is gone: its freed memory goes back
            trim_heap(self.M_.element_size() * self.M_.numel())

    def _fit_all(self, names: list[str], fit_missing: Tensor, stage: str = "fit",
                 case: tuple | None = None) -> Iterator:
        """:meth:`_attempt` for each name, in order; on CPU in threads (``runtime.threads``).
        Each finished fit is reported (:meth:`Solver.report`): ``{stage}=k``, ``{stage}s=n``
        (``fit``/``fits`` on the hold-out, ``refit``/``refits``; the step's own record counts the
        ``candidates`` that ran)."""
        workers = None if self.M_.device.type == "cpu" else 1
        lock, done = threading.Lock(), [0]

        def attempt(name: str):
            out = self._attempt(name, fit_missing, case)
            with lock:
                done[0] += 1
                self.report({stage: float(done[0]), f"{stage}s": float(len(names))})
            return out
        return thread_map(attempt, names, workers,
                              cost=lambda name: COST.get(name.removesuffix(SESSION), 1.0))

    def _run_candidates(self, fit_missing: Tensor) -> tuple[list[str], Tensor]:
        """Each candidate fitted once with ``fit_missing`` hidden: names and fills (C, T, J, 3)."""
        names, fills = [], []
        every = self.candidate_names()
        for name, out in zip(every, self._fit_all(every, fit_missing)):
            if isinstance(out, Exception):
                self.dropped_[name] = str(out)
                continue
            names.append(name)
            fills.append(out)
        if not names:
            raise ValueError(f"{self.name}: every candidate failed on this recording: "
                             + "; ".join(f"{k}: {v}" for k, v in self.dropped_.items()))
        return names, torch.stack(fills)

    def _refit(self, names: list[str], fills: Tensor, w: Tensor,
               gaps: Tensor) -> tuple[Tensor, Tensor]:
        """Fills of the real ``gaps`` from the candidates that carry weight there, refitted on all
        observed samples (the hold-out fit stays where the refit fails), constrained like the
        hold-out fills; and the (T, J) samples that rigid donors fill."""
        fills = fills.clone()
        done = [c for c in range(len(names)) if bool((w[c][gaps] > 0).any())]
        for c, out in zip(list(done), self._fit_all([names[c] for c in done], gaps, "refit")):
            if isinstance(out, Exception):
                done.remove(c)
            else:
                fills[c] = torch.where(gaps[..., None], out, fills[c])
        Xt = self.M_.reshape(fills.shape[1:])
        seen = torch.where(gaps[..., None], fills[done], Xt)   # held-out samples as observed
        refits, donor = self._constrain(seen, gaps)
        fills[done] = torch.where(gaps[..., None], refits, fills[done])
        return fills, donor

    def _constrain(self, fills: Tensor, missing: Tensor) -> tuple[Tensor, Tensor]:
        """Each candidate's fill (C, T, J, D) after the post-step given as ``post`` fit data
        (``fill()`` passes :func:`torchfill.constraints.constrain_candidates` when its constraints
        are on), and the (T, J) samples that rigid donors fill there. Unchanged, with no donors,
        without a post-step."""
        post = self.fit_data_.get("post")
        if post is None or fills.shape[0] == 0:
            return fills, torch.zeros_like(missing)
        with warnings.catch_warnings():     # the candidates' post-step speaks to no one: the
            warnings.simplefilter("ignore")  # final fill's own post-step warns the user once
            out = post(fills, missing)
        trim_heap(self.M_.element_size() * self.M_.numel())
        return out

    @staticmethod
    def _speed2(step: Tensor, both: Tensor) -> Tensor:
        """Per marker (J,), the mean squared one-frame step over the frame pairs ``both`` (T-1, J)
        where it is seen twice in a row; a marker never seen so takes the median of the others:
        its speed is unknown, not zero (bench_ik's ktk_basket_sprint mask at 60 Hz: nine markers
        seen only in isolated frames got estimates of 0.3-0.6 mm for errors of 24-627 mm)."""
        n = both.sum(dim=0)
        speed2 = torch.where(both, step, 0.0).sum(dim=0) / n.clamp(min=1)
        if bool((n > 0).any()):
            speed2 = torch.where(n > 0, speed2, speed2[n > 0].median())
        return speed2

    @staticmethod
    def _spread2(fills: Tensor, mean: Tensor, mse: Tensor) -> Tensor:
        """(T, J) disagreement of all candidates with the combined fill, each weighted by its
        inverse held-out mean squared error ``mse`` (C,) (so a poor candidate counts little)."""
        v = 1.0 / mse.clamp(min=1e-12)
        v = (v / v.sum())[:, None, None, None]
        return (v * (fills - mean) ** 2).sum(dim=0).mean(dim=2)

    def _fit_std(self, V: Tensor, seen: Tensor, features: tuple, e2: Tensor) -> None:
        """Fit the error model on the held-out samples and predict it on the real gaps."""
        gaps = ~seen
        d, L, edge, share, spread2, bend2, speed2, motion, donor = features
        F_all = error_features(d.clamp(min=1), L.clamp(min=1), edge, share.clamp(min=1e-3),
                               spread2, bend2, speed2, motion, donor)
        if int(V.sum()) >= 10:
            beta, log_scale = fit_error_model(F_all[V], e2[V])
            high = float(torch.quantile(motion[V], 0.9).clamp(min=1e-12))
            self.error_model_ = (beta.tolist(), log_scale, high)
        elif self.choice is None:
            self.error_model_ = None
        if self.error_model_ is not None:         # fitted here, or an earlier window's
            beta, log_scale, high = self.error_model_
            beta = torch.tensor(beta, dtype=F_all.dtype, device=F_all.device)
            var = torch.exp(F_all[gaps] @ beta + log_scale)
            # beyond the motion the hold-out saw, the error grows with the motion (not fitted)
            var = var * (motion[gaps] / high).clamp(min=1.0)
        else:                                            # no hold-out: spread of the candidates
            var = spread2[gaps] + 1e-8
        std = torch.full_like(spread2, float("nan"))
        std[gaps] = var.sqrt() * self.sigma_
        self.std_ = std
