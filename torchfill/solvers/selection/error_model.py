"""The error estimate ``std_`` of the default's fill: a log-linear model of the held-out squared
error of the combined fill on features of each sample (distance to the nearest observed frame,
gap length, trial end, share of markers missing in the frame, the candidates' disagreement, the
fill's departure from linear interpolation, the marker's observed speed, the gap's frame motion,
rigid donors), fitted on the held-out samples, scaled so that the mean ratio of squared error to
estimated variance there is 1, and grown in proportion to the motion beyond the 90th percentile
of the hold-out's motion (which the fit cannot see). Calibration: docs/real-gaps.md."""
from __future__ import annotations

import torch

from ... import ops

Tensor = torch.Tensor


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
    gaps (``~seen``; NaN elsewhere), in the data's units (``sigma``). ``features``: ``d, L,
    edge, share, spread2, bend2, speed2, motion, donor`` per sample. Returns (model, std)."""
    gaps = ~seen
    d, L, edge, share, s2, bend2, sp2, motion, donor = features
    F_all = error_features(d.clamp(min=1), L.clamp(min=1), edge, share.clamp(min=1e-3),
                           s2, bend2, sp2, motion, donor)
    if int(V.sum()) >= 10:
        beta, log_scale = fit_error_model(F_all[V], e2[V])
        high = float(torch.quantile(motion[V], 0.9).clamp(min=1e-12))
        model = (beta.tolist(), log_scale, high)
    if model is not None:                     # fitted here, or an earlier window's
        beta, log_scale, high = model
        beta = torch.tensor(beta, dtype=F_all.dtype, device=F_all.device)
        var = torch.exp(F_all[gaps] @ beta + log_scale)
        # beyond the motion the hold-out saw, the error grows with the motion (not fitted)
        var = var * (motion[gaps] / high).clamp(min=1.0)
    else:                                            # no hold-out: spread of the candidates
        var = s2[gaps] + 1e-8
    std = torch.full_like(s2, float("nan"))
    std[gaps] = var.sqrt() * sigma
    return model, std
