"""Per-kind weights of the candidates from their held-out errors, and their combination on each
gap (:func:`consensus`, :func:`join_holes`). Measurements behind each rule:
experiments/results/auto.md and docs/real-gaps.md."""
from __future__ import annotations

import torch

from ... import ops
from .kinds import run_bounds

Tensor = torch.Tensor

#: A kind's held-out errors count as much as their number of held-out gaps against this many
#: gaps of its parent (all gaps at a trial end / inside, then all gaps, each among the samples
#: a partial candidate fills or among the others): see :func:`kind_mse`.
PRIOR_GAPS = 10.0


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
    held-out gaps does not pick a candidate that won there by chance.

    With ``partial_from`` (even), the kinds from that index on are those a partial candidate
    fills, and their parents are taken among their own samples: the partial candidate is scored
    on those only, while a parent over all gaps held the others' errors where it does not fill,
    so it would win its kinds on the shrinkage alone. The other kinds keep the parents over all
    gaps (every candidate there fills every sample)."""
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
    there (measured: docs/real-gaps.md)."""
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


def join_holes(mean: Tensor, fills: Tensor, w: Tensor, partial: Tensor,
               missing: Tensor) -> Tensor:
    """``mean`` (T, J, D) with each hole in a partial candidate's fill (missing samples it
    leaves NaN between samples it fills: a mate hidden for some frames of the gap) shifted by
    the linear ramp between its offsets at the two sides from the samples beside it, so the
    other candidates' fill meets the segment fill instead of stepping to it (the time
    constraint of Tits et al. with the segment fill as the border). A hole that reaches an
    observed sample or a trial end is left as it is (measured: experiments/results/auto.md)."""
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
