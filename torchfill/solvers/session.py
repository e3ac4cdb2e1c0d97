"""Other recordings of the same marker set as training evidence: stacked onto the recording along
time for the model fit, only the recording's own rows filled.

A spatial model (a marker placed from the markers seen in the same frame: the PMA family,
Gløersen PCA) learns from frames, not from their order, so frames of the subject's other trials
are evidence for it just as the recording's own are. :func:`stack` appends them after the
recording's frames; the models train on every observed sample of the stack and fill the
recording's gaps only (``todo``), with the time constraints of the recording's own gap edges
(a gap at the recording's last frame stays a trial-end gap: the pieces are kept apart, see
:func:`piecewise`). The training recordings are never changed: the stack is a new tensor.

At most ``TRAINING_FRAMES`` training frames are used, in ``BLOCK``-frame runs spread evenly over
the training recordings, so the cost of a fill grows with the recording and not with the session.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

Tensor = torch.Tensor

#: Training frames stacked at most (all training recordings together): the spatial models read
#: at most 1000 frames for their regressions, and more frames only slow the filters and PCA.
TRAINING_FRAMES = 2000
#: Training frames are taken in runs of this many consecutive frames (filters need neighbours).
BLOCK = 100


def training_rows(training: Sequence[Tensor], mu: Tensor, sigma: Tensor,
                  budget: int | None = None, block: int = BLOCK) -> list[Tensor]:
    """The training recordings in a fit's normalized units (``(t - mu) / sigma``), cut to at most
    ``budget`` frames (default ``TRAINING_FRAMES``, read at the call) in runs of ``block`` frames
    evenly spread over all of them; frames with no observed marker are dropped. New tensors: the
    training data are not changed."""
    budget = TRAINING_FRAMES if budget is None else budget
    items = [torch.as_tensor(t).to(dtype=mu.dtype, device=mu.device) for t in training]
    items = [t[torch.isfinite(t).all(dim=-1).any(dim=-1)] for t in items]
    items = [t for t in items if t.shape[0] > 0]
    total = sum(t.shape[0] for t in items)
    if total == 0:
        return []
    if total > budget:
        share = budget / total
        items = [spread_runs(t, max(block, int(round(t.shape[0] * share))), block)
                 for t in items]
    return [(t - mu) / sigma for t in items]


def spread_runs(t, keep: int, block: int = BLOCK):
    """``keep`` frames of ``t`` (a tensor or an array, time first) in runs of ``block`` frames
    evenly spaced (all of ``t`` if it is shorter)."""
    T = t.shape[0]
    if keep >= T:
        return t
    n = max(1, keep // block)
    starts = [round(i * (T - block) / max(n - 1, 1)) for i in range(n)] if T > block else [0]
    parts = [t[s:s + block] for s in starts]
    return torch.cat(parts) if isinstance(t, Tensor) else np.concatenate(parts)


def stack(P: Tensor, missing: Tensor, train: Sequence[Tensor]
          ) -> tuple[Tensor, Tensor, Tensor, list[tuple[int, int]]]:
    """The recording ``P`` (T, J, D; NaN where ``missing``) with the ``train`` pieces (T_i, J, D,
    NaN where not observed) appended along time. Returns the stack, its missing mask, ``todo``
    (the recording's gaps: what to fill; False on training rows) and the pieces' row ranges."""
    T = P.shape[0]
    pieces, at = [(0, T)], T
    for t in train:
        pieces.append((at, at + t.shape[0]))
        at += t.shape[0]
    if len(pieces) == 1:
        return P, missing, missing, pieces
    seen = [torch.isfinite(t).all(dim=-1) for t in train]
    P_all = torch.cat([P, *[torch.where(s[..., None], t, torch.nan) for t, s in zip(train, seen)]])
    missing_all = torch.cat([missing, *[~s for s in seen]])
    todo = torch.zeros_like(missing_all)
    todo[:T] = missing
    return P_all, missing_all, todo, pieces


def piecewise(f: Callable[[Tensor], Tensor], X: Tensor, pieces: list[tuple[int, int]]) -> Tensor:
    """``f`` applied along time to each piece of the stack ``X`` on its own (filters do not mix
    the end of one recording with the start of the next)."""
    if len(pieces) == 1:
        return f(X)
    return torch.cat([f(X[a:b]) for a, b in pieces])
