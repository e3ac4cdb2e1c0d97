"""The one hold-out component: observed samples hidden from a solver's own fit to choose a rank, an
iterate or a method (the ground truth of the missing samples is never used).

Two parts:

* **which** observed samples to hide -- :func:`shifted_gap_holdout` (the recording's gap pattern
  moved in time), :func:`segment_holdout` (single-marker observed runs, a fixed number),
  :func:`run_holdout` (gap-shaped runs up to a share of the samples), :func:`mirrored_edge_holdout`
  (trial-end gaps mirrored onto the other end); :func:`select_holdout` picks one by name, the
  values of the ``holdout`` hyperparameter;
* :class:`HoldOut` -- hide that mask, score iterates on it, keep the best state, restore it and
  give the data back. Tucker, the CP family and the gradient fits all go through it.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch

from .. import ops
from .base import Param, Solver

Tensor = torch.Tensor

#: names of the hold-out kinds (the values of every solver's ``holdout`` hyperparameter; None: off)
KINDS = ("shifted_gaps", "segments", "runs")


def _samples(Omega: Tensor) -> Tensor:
    """(T, J) bool: the samples (frame, marker) with every coordinate observed."""
    return Omega.reshape(Omega.shape[0], Omega.shape[1], -1).all(dim=2)


def _entries(V: Tensor, Omega: Tensor) -> Tensor:
    """A (T, J) sample mask spread over ``Omega``'s trailing modes, restricted to observed entries."""
    return V.reshape(V.shape + (1,) * (Omega.ndim - 2)).expand_as(Omega) & Omega


def median_gap(Omega: Tensor) -> int:
    """Median length in frames of the gaps of ``Omega`` (0 when there is none)."""
    lengths = [b - a for _, a, b in ops.runs(~_samples(Omega))]
    return int(sorted(lengths)[len(lengths) // 2]) if lengths else 0


def _best_shift(gaps: Tensor, seen: Tensor, shifts: list[int]) -> Tensor:
    """The gap pattern rolled along time by the shift that keeps most of it on observed samples,
    each marker's share capped at half of its observed samples (markers over it are dropped)."""
    best, best_count = None, -1
    for tau in shifts:
        V = torch.roll(gaps, tau, dims=0) & seen
        V = V & (V.sum(dim=0) <= 0.5 * seen.sum(dim=0))
        count = int(V.sum())
        if count > best_count:
            best, best_count = V, count
    return best


def shifted_gap_holdout(Omega: Tensor, generator: torch.Generator, max_share: float = 0.2,
                        n_shifts: int = 16) -> Tensor | None:
    """Observed entries to hold out for the rank choice: the gap pattern shifted in time.

    The missing (frame, marker) pattern is rolled along time by the candidate shift (of
    ``n_shifts`` random ones in [T/10, 9T/10]) that keeps most of it on observed samples, so the
    held-out segments have the lengths, markers and simultaneity of the real gaps. No marker
    loses more than half of its observed samples to the hold-out; when that leaves nothing (a gap
    covering half the recording), the pattern is moved to randomly permuted markers as well.
    At most ``max_share`` of the observed samples are held out (whole markers dropped from the
    hold-out at random beyond that). Returns a bool mask of ``Omega``'s shape, or None when there
    is nothing to hold out.
    """
    T = Omega.shape[0]
    seen = _samples(Omega)
    gaps = ~seen
    if T < 10 or not bool(gaps.any()) or not bool(seen.any()):
        return None
    low, high = max(1, T // 10), max(2, (9 * T) // 10)
    shifts = torch.randint(low, high, (n_shifts,), generator=generator,
                           device=generator.device).tolist()
    V = _best_shift(gaps, seen, shifts)
    if not bool(V.any()):
        perm = torch.randperm(gaps.shape[1], generator=generator,
                              device=generator.device).to(gaps.device)
        V = _best_shift(gaps[:, perm], seen, shifts)
    cap = max_share * float(seen.sum())
    if float(V.sum()) > cap:
        order = torch.randperm(V.shape[1], generator=generator, device=generator.device).tolist()
        keep = torch.zeros(V.shape[1], dtype=torch.bool, device=V.device)
        total = 0.0
        for j in order:
            c = float(V[:, j].sum())
            if total + c <= cap:
                keep[j] = True
                total += c
        V = V & keep
    if not bool(V.any()):
        return None
    return _entries(V, Omega)


def _edge_runs(gaps: Tensor) -> Tensor:
    """The part of ``gaps`` (T, J) that touches the first or the last frame."""
    head = torch.cumprod(gaps.to(torch.int8), dim=0).bool()
    tail = torch.cumprod(gaps.flip(0).to(torch.int8), dim=0).bool().flip(0)
    return head | tail


def mirrored_edge_holdout(Omega: Tensor) -> Tensor | None:
    """Observed entries to hold out like the gaps at the trial ends: each marker's gap at the start
    (end) mirrored onto its end (start), where the marker is observed up to that end.

    Complements :func:`shifted_gap_holdout`, whose time shift moves trial-end gaps inside the
    recording (interpolation) while the real ones are extrapolations. No marker loses more than
    half of its observed samples. Returns a bool mask of ``Omega``'s shape, or None.
    """
    T = Omega.shape[0]
    seen = _samples(Omega)
    if T < 10 or not bool(seen.any()):
        return None
    V = _edge_runs(_edge_runs(~seen).flip(0) & seen)
    V = V & (V.sum(dim=0) <= 0.5 * seen.sum(dim=0))
    if not bool(V.any()):
        return None
    return _entries(V, Omega)


def segment_holdout(Omega: Tensor, n_segments: int, length: int | None,
                    generator: torch.Generator) -> Tensor:
    """``n_segments`` runs of ``length`` frames on random markers where the marker is observed
    throughout (and not next to another chosen run); returns the held-out mask (``Omega``'s shape).

    ``length=None`` uses the median length of the recording's own gaps, clipped to
    ``[5, T // 8]`` (50 when there is no gap). Only positions of observed samples are used.
    """
    obs = _samples(Omega)
    T, J = obs.shape
    length = length if length is not None else (median_gap(Omega) or 50)
    length = int(max(1, min(max(length, 5), max(T // 8, 1))))
    hold = torch.zeros(T, J, dtype=torch.bool, device=Omega.device)
    if T < 4 * length or n_segments == 0:
        return _entries(hold, Omega).clone()
    # a run may start at t if obs[t:t+length] all True (cumulative counts), with a margin of one
    c = torch.cat([torch.zeros(1, J, dtype=torch.long, device=Omega.device),
                   torch.cumsum(obs.long(), dim=0)])
    ok = (c[length:] - c[:-length]) == length                                 # (T-length+1, J)
    tried = 0
    while int(hold.any(dim=0).sum()) < J and tried < 20 * n_segments:
        tried += 1
        j = int(torch.randint(J, (1,), generator=generator, device=generator.device))
        starts = torch.nonzero(ok[:, j]).flatten()
        if starts.numel() == 0:
            continue
        a = int(starts[int(torch.randint(starts.numel(), (1,), generator=generator,
                                         device=generator.device))])
        lo, hi = max(0, a - length), min(T, a + 2 * length)
        if bool(hold[lo:hi, j].any()):
            continue
        hold[a:a + length, j] = True
        if len(ops.runs(hold)) >= n_segments:
            break
    return _entries(hold, Omega).clone()


def run_holdout(Omega: Tensor, share: float, length: int | None,
                generator: torch.Generator) -> Tensor:
    """Gap-shaped runs of ``length`` frames of observed samples on random markers, drawn until
    about ``share`` of the observed samples are held out; no marker loses more than half of its
    samples. ``length=None``: the median length of the recording's gaps (10 when none)."""
    T = Omega.shape[0]
    obs = _samples(Omega)
    target = share * float(obs.sum())
    held = torch.zeros_like(obs)
    length = length if length is not None else (median_gap(Omega) or 10)
    length = max(1, min(length, T // 4))
    for _ in range(10_000):
        if float(held.sum()) >= target:
            break
        j = int(torch.randint(obs.shape[1], (1,), generator=generator, device=obs.device))
        t0 = int(torch.randint(max(1, T - length + 1), (1,), generator=generator, device=obs.device))
        free = obs[t0:t0 + length, j] & ~held[t0:t0 + length, j]
        kept = int((obs[:, j] & ~held[:, j]).sum()) - length
        if bool(free.all()) and kept >= int(obs[:, j].sum()) // 2:   # keep half of each marker
            held[t0:t0 + length, j] = True
    return _entries(held, Omega)


def select_holdout(kind: str | None, Omega: Tensor, generator: torch.Generator, *,
                   share: float, n_segments: int = 12, length: int | None = None) -> Tensor | None:
    """The held-out mask of the named kind (see :data:`KINDS`), or None (``kind=None`` or nothing
    to hold out). ``shifted_gaps`` falls back to ``segments`` when the pattern finds no room."""
    if kind is None:
        return None
    if kind not in KINDS:
        raise ValueError(f"holdout expected one of {KINDS} or None, found {kind!r}")
    V = None
    if kind == "shifted_gaps":
        V = shifted_gap_holdout(Omega, generator, max_share=share)
        kind = "segments" if V is None else kind
    if kind == "segments":
        V = segment_holdout(Omega, n_segments, length, generator)
    elif kind == "runs":
        V = run_holdout(Omega, share, length, generator)
    return V if V is not None and bool(V.any()) else None


def holdout_params(kind: str | None, share: float, why: str = "") -> dict[str, Param]:
    """The hold-out hyperparameters, the same names and meanings in every solver that has one."""
    return {
        "holdout": Param(kind, str, choices=KINDS, allow_none=True,
                         doc="observed samples hidden from the fit to choose the rank/iterate: "
                             "'shifted_gaps' = the recording's own gap pattern moved in time onto "
                             "observed samples (falls back to 'segments'); 'segments' = "
                             "single-marker observed runs; 'runs' = gap-shaped runs up to "
                             "holdout_share; None = no hold-out" + why),
        "holdout_share": Param(share, float, low=0.0, high=1.0, low_open=True,
                               doc="at most this share of the observed samples is held out "
                                   "('shifted_gaps', 'runs')"),
        "holdout_segments": Param(12, int, low=1, doc="number of held-out runs ('segments')"),
        "holdout_length": Param(None, int, low=1, allow_none=True,
                                doc="frames per held-out run ('segments', 'runs'; None: the "
                                    "median length of the recording's gaps)"),
    }


def holdout_for(solver: Solver, **kwargs: float) -> HoldOut:
    """The :class:`HoldOut` of a fitting solver, from its hold-out hyperparameters."""
    V = select_holdout(solver.holdout, solver.Omega_, solver.generator_, share=solver.holdout_share,
                       n_segments=solver.holdout_segments, length=solver.holdout_length)
    return HoldOut(solver.Omega_, V, **kwargs)


class HoldOut:
    """Observed samples hidden from a fit: score iterates on them, keep the best, give them back.

    Parameters
    ----------
    Omega : Tensor of bool
        The observed entries.
    V : Tensor of bool or None
        The entries to hide (a subset of ``Omega``); None or empty: an inactive hold-out (the fit
        sees everything and :meth:`rmse` is nan).
    min_gain, atol : float
        A score counts as better only below ``(1 - min_gain) * best - atol``.

    Attributes
    ----------
    fit_mask : Tensor of bool
        What the fit may see: ``Omega & ~V`` while active, ``Omega`` once released.
    best_score, best_state, best_iter : the best offer so far.
    n_bad : int
        Offers since the last improvement.
    """

    def __init__(self, Omega: Tensor, V: Tensor | None, *, min_gain: float = 0.0,
                 atol: float = 0.0) -> None:
        self.Omega = Omega
        self.V = V if V is not None and bool(V.any()) else None
        self.active = self.V is not None
        self.fit_mask = Omega & ~self.V if self.active else Omega
        self.n_held = int(self.V.sum()) if self.active else 0
        self._index = self.V.reshape(-1).nonzero().squeeze(1) if self.active else None   # flat
        self.min_gain, self.atol = min_gain, atol
        self.best_score, self.best_state, self.best_iter = math.inf, None, 0
        self.n_bad = 0

    def rmse(self, X: Tensor, M: Tensor) -> float:
        """RMSE of ``X`` against the data ``M`` over the held-out entries (nan when inactive)."""
        if self.V is None:
            return math.nan
        i = self._index
        return float(torch.dist(X.reshape(-1).index_select(0, i), M.reshape(-1).index_select(0, i))
                     ) / math.sqrt(max(self.n_held, 1))

    def offer(self, score: float, state: Callable[[], Any], iteration: int = 0) -> bool:
        """Keep ``state()`` (called only then) if ``score`` beats the best; returns whether it did."""
        if self.best_state is None or score < (1.0 - self.min_gain) * self.best_score - self.atol:
            self.best_score, self.best_state, self.best_iter = score, state(), iteration
            self.n_bad = 0
            return True
        self.n_bad += 1
        return False

    def release(self) -> Any:
        """Give the held-out data back (``fit_mask`` becomes ``Omega``); returns the best state."""
        self.active = False
        self.fit_mask = self.Omega
        return self.best_state
