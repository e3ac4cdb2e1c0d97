"""The cross-trial hold-out: with training recordings (the subject's other trials), the
recording's own gap pattern laid whole onto the training recording whose motion is nearest, so a
trial-end gap kind is weighed by how each candidate fills exactly this pattern on this subject.
Measured on the session suite: docs/real-gaps.md."""
from __future__ import annotations

import torch

from .candidates import Fits
from .draws import scored

Tensor = torch.Tensor

#: Window starts tried for the cross-trial hold-out (:func:`motion_match`), every this many frames.
MATCH_STRIDE = 10


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


def _nearest_window(fits: Fits, seen: Tensor, training: list) -> tuple | None:
    """The training recording (index) and the ``T``-frame window of it, in the fit's units,
    whose motion is nearest to the recording's (:func:`motion_match`); None when every training
    recording is shorter than the recording."""
    T, J = seen.shape
    Y = fits.M.reshape(T, J, -1)
    best = None
    for k, t in enumerate(training):
        if t.shape[0] < T:
            continue
        Z = (t.reshape(t.shape[0], J, -1) - fits.mu) / fits.sigma
        start, cost = motion_match(Y, seen, Z)
        if best is None or cost < best[0]:
            best = (cost, k, start, Z[start:start + T])
    return None if best is None else best[1:]


def cross_holdout(fits: Fits, names: list[str], seen: Tensor
                  ) -> tuple[tuple | None, tuple | None, dict]:
    """The recording's own gaps, whole (all markers together, where they are), laid onto the
    nearest ``T``-frame window of a training recording (:func:`_nearest_window`). Each candidate
    fills it (a ``+session`` twin with the recording's observed samples and the other training
    recordings as its training, the others on the window alone), through the post-step, and is
    scored on the training recording's observed samples under the laid gaps. Reads the
    recording's observed samples only.

    Returns ``(scored, window, scores)``: the squared errors (C, N) (NaN: the candidate failed
    there), the samples' kinds and gap indices, without the samples rigid donors fill (None
    without training data, or where a marker would be seen nowhere in the window); the window
    (training index, start; None: none); the RMSE per candidate (empty where it did not run)."""
    training = fits.fit_data.get("training")
    if not training:
        return None, None, {}
    T, J = seen.shape
    best = _nearest_window(fits, seen, training)
    if best is None:
        return None, None, {}
    k, start, Z = best
    window = (k, start)
    gaps = ~seen
    obs = torch.isfinite(Z).all(dim=-1)
    missing = gaps | ~obs
    if not bool((gaps & obs).any()) or not bool((~missing).any(dim=0).all()):
        return None, window, {}
    M = fits.M
    Mx = torch.nan_to_num(Z).reshape(M.shape)
    own = torch.where(seen.reshape(T, J, 1), M.reshape(T, J, -1), float("nan"))
    train = [own.reshape(M.shape)] + [(t - fits.mu) / fits.sigma
                                      for i, t in enumerate(training) if i != k]
    outs = list(fits.fit_all(names, missing, "cross", (Mx, train)))
    if all(isinstance(out, Exception) for out in outs):
        return None, window, {}
    got, err2, _ = scored(fits, names, outs, missing, Mx.reshape(T, J, -1), gaps & obs)
    return got, window, {nm: float(e.nanmean().sqrt()) for nm, e in zip(names, err2)}
