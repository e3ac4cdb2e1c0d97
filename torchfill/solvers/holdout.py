"""Validation data from observed samples only: which observed entries a solver hides from its own
fit to choose a rank or an iterate (the ground truth of the missing samples is never used).
"""
from __future__ import annotations

import torch

Tensor = torch.Tensor


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
    seen = Omega.reshape(T, Omega.shape[1], -1).all(dim=2)                 # (T, J) samples
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
    return V.reshape(V.shape + (1,) * (Omega.ndim - 2)).expand_as(Omega) & Omega


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
    seen = Omega.reshape(T, Omega.shape[1], -1).all(dim=2)
    if T < 10 or not bool(seen.any()):
        return None
    V = _edge_runs(_edge_runs(~seen).flip(0) & seen)
    V = V & (V.sum(dim=0) <= 0.5 * seen.sum(dim=0))
    if not bool(V.any()):
        return None
    return V.reshape(V.shape + (1,) * (Omega.ndim - 2)).expand_as(Omega) & Omega
