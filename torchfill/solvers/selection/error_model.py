"""The error estimate ``std_`` of the default's fill: a log-linear model of the held-out squared
error of the combined fill on features of each sample (distance to the nearest observed frame,
gap length, trial end, share of markers missing in the frame, the candidates' disagreement, their
spread around the fill by the weights that make it, the fill's departure from linear
interpolation, the marker's observed speed, the gap's frame motion, rigid donors), fitted on the
held-out samples, scaled so that the mean ratio of squared error to estimated variance there is 1,
and grown in proportion to the motion beyond the 90th percentile of the hold-out's motion (which
the fit cannot see). On the real gaps each feature is held within the range the hold-out spans: a
log-linear fit does not extrapolate (a trial end standing still is not a hold-out gap in motion,
experiments/results/qc.md). Calibration: docs/real-gaps.md."""
from __future__ import annotations

import torch

from ... import ops

Tensor = torch.Tensor


#: Columns of :func:`error_features` that are counts or 0/1 (the intercept, trial end, donor):
#: not held within the hold-out's range.
DISCRETE = (0, 3, 9)


def error_features(d: Tensor, L: Tensor, edge: Tensor, share: Tensor, spread2: Tensor,
                   bend2: Tensor, speed2: Tensor, motion: Tensor, donor: Tensor,
                   mix2: Tensor) -> Tensor:
    """Design matrix (..., 11) of the log-linear error model (see the module notes)."""
    dtype = spread2.dtype
    return torch.stack([torch.ones_like(spread2), torch.log(d.to(dtype)), torch.log(L.to(dtype)),
                        edge.to(dtype), torch.log(share.to(dtype)), torch.log(spread2 + 1e-8),
                        torch.log(bend2 + 1e-8), torch.log(speed2 + 1e-8),
                        torch.log(motion + 1e-3), donor.to(dtype), torch.log(mix2 + 1e-8)],
                       dim=-1)


def fit_error_model(F: Tensor, e2: Tensor, ridge: float = 1e-3) -> tuple[Tensor, float]:
    """Least squares of ``log e2`` on the features ``F`` (ridge on the slopes), then the scale that
    makes the mean of ``e2`` over the predicted variance 1. Returns (coefficients, log scale)."""
    y = torch.log(e2 + 1e-10)
    R = ridge * torch.eye(F.shape[1], dtype=F.dtype, device=F.device) * F.shape[0]
    R[0, 0] = 0.0
    beta = torch.linalg.solve(F.T @ F + R, F.T @ y)
    log_scale = float(torch.log(torch.mean(e2 / torch.exp(F @ beta))))
    return beta, log_scale


def speed2(step: Tensor, both: Tensor) -> Tensor:
    """Per marker (J,), the mean squared one-frame step over the frame pairs ``both`` (T-1, J)
    where it is seen twice in a row; a marker never seen so takes the median of the others:
    its speed is unknown, not zero."""
    n = both.sum(dim=0)
    s2 = torch.where(both, step, 0.0).sum(dim=0) / n.clamp(min=1)
    if bool((n > 0).any()):
        s2 = torch.where(n > 0, s2, s2[n > 0].median())
    return s2


def spread2(fills: Tensor, mean: Tensor, mse: Tensor) -> Tensor:
    """(T, J) disagreement of all candidates with the combined fill, each weighted by its
    inverse held-out mean squared error ``mse`` (C,) (so a poor candidate counts little)."""
    v = 1.0 / mse.clamp(min=1e-12)
    v = (v / v.sum())[:, None, None, None]
    return (v * (fills - mean) ** 2).sum(dim=0).mean(dim=2)


def mix2(fills: Tensor, mean: Tensor, w: Tensor) -> Tensor:
    """(T, J) spread of the candidates' ``fills`` (C, T, J, D) around the combined fill ``mean``
    by the weights ``w`` (C, T, J) that make it: the variance of the mixture the fill is the mean
    of (the candidates it leaves out do not count)."""
    return (w * ((fills - mean) ** 2).mean(dim=3)).sum(dim=0)


def sample_features(fills: Tensor, mean: Tensor, mse: Tensor, missing: Tensor, Xt: Tensor
                    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per (T, J) sample: the share of markers ``missing`` in its frame, the candidates'
    disagreement (:func:`spread2`), the combined fill ``mean``'s departure from linear
    interpolation of ``Xt`` (T, J, D) and its marker's observed speed (:func:`speed2`)."""
    s2 = spread2(fills, mean, mse)
    share = missing.to(fills.dtype).mean(dim=1, keepdim=True).expand_as(s2)
    lin = ops.interp_linear(Xt.reshape(Xt.shape[0], -1),                # V hidden too
                            (~missing[..., None]).expand_as(Xt).reshape(Xt.shape[0], -1)
                            ).reshape(Xt.shape)
    bend2 = ((mean - lin) ** 2).mean(dim=2)                     # motion the fill adds
    step = torch.diff(Xt, dim=0).pow(2).mean(dim=2)
    both = ~missing[1:] & ~missing[:-1]
    return share, s2, bend2, speed2(step, both).expand_as(s2)


def fit_std(V: Tensor, seen: Tensor, features: tuple, e2: Tensor, model: tuple | None,
            sigma: Tensor) -> tuple[tuple | None, Tensor]:
    """The error model fitted on the held-out samples ``V`` (T, J) with squared errors ``e2``
    (else ``model``, an earlier window's, or None), and the std (T, J) it predicts on the real
    gaps (``~seen``; NaN elsewhere), in the data's units (``sigma``), each feature held within
    the range of its held-out values. ``features``: ``d, L, edge, share, spread2, bend2, speed2,
    motion, donor, mix2`` per sample. Returns (model, std)."""
    gaps = ~seen
    d, L, edge, share, s2, bend2, sp2, motion, donor, m2 = features
    F_all = error_features(d.clamp(min=1), L.clamp(min=1), edge, share.clamp(min=1e-3),
                           s2, bend2, sp2, motion, donor, m2)
    if int(V.sum()) >= 10:
        beta, log_scale = fit_error_model(F_all[V], e2[V])
        high = float(torch.quantile(motion[V], 0.9).clamp(min=1e-12))
        lo, hi = F_all[V].min(dim=0).values, F_all[V].max(dim=0).values
        model = (beta.tolist(), log_scale, high, lo.tolist(), hi.tolist())
    if model is not None:                     # fitted here, or an earlier window's
        beta, log_scale, high, lo, hi = (torch.tensor(v, dtype=F_all.dtype, device=F_all.device)
                                         if isinstance(v, list) else v for v in model)
        held = torch.ones_like(lo, dtype=torch.bool)
        held[list(DISCRETE)] = False
        F = F_all[gaps]
        F = torch.where(held, torch.minimum(torch.maximum(F, lo), hi), F)   # no extrapolation
        var = torch.exp(F @ beta + log_scale)
        # beyond the motion the hold-out saw, the error grows with the motion (not fitted)
        var = var * (motion[gaps] / high).clamp(min=1.0)
    else:                                            # no hold-out: spread of the candidates
        var = s2[gaps] + 1e-8
    std = torch.full_like(s2, float("nan"))
    std[gaps] = var.sqrt() * sigma
    return model, std
