"""PredictMissingMarkers of Gløersen & Federolf (2016), strategy R2: ``pca_gloersen``.

Each marker with gaps is reconstructed on its own from a marker-intercorrelation PCA (Federolf
2013, Eq. 1): the frames where every kept marker is observed train two PCA bases, one of the full
data and one with the gapped marker zeroed; the gap frames are mapped through the second into the
first. Columns are normalized to unit variance and weighted by a Gaussian of the distance to the
gapped marker (the gapped marker itself gets ``mm_weight``); markers that are themselves missing
during that marker's gap, or gapped and distal, are zeroed (R2).

Where the original fails, this one does better:

- the original centres every frame on the mean of the never-missing markers and returns nothing
  when every marker has a gap somewhere. Here the centre is the mean of all markers after linear
  interpolation in time when no marker is complete (the original centre when one is);
- frames of a gap where no other marker is observed (whole-frame blackouts) carry no spatial
  information: the original returns the mean pose there; here that gap is linearly interpolated,
  and so is a marker left with fewer than 3 other markers to map from (R2 drops every marker
  missing during its gaps; on a real recording one reference gave 1 m jumps at a gap edge);
- distances and weights are relative to the mean distance between markers (unit invariant), not mm.

References
----------
Federolf PA (2013). A novel approach to solve the "missing marker problem" in marker-based motion
analysis that exploits the segment coordination patterns in multi-limb motion data. PLoS ONE 8(10).
Gløersen Ø, Federolf P (2016). Predicting missing marker trajectories in human motion data using
marker intercorrelations. PLoS ONE 11(3): e0152616.
"""
from __future__ import annotations

import torch

from .. import ops
from ..runtime.cache import Memo
from . import session
from .base import OneShotSolver, Param, register

Tensor = torch.Tensor


def body_centre(P: Tensor, missing: Tensor) -> Tensor:
    """Per-frame centre ``(T, 3)``: mean of the never-missing markers (Gløersen & Federolf, the
    moving coordinate system); when every marker has a gap, the mean of all markers linearly
    interpolated in time (the original has no centre then and fills nothing)."""
    full = ~missing.any(dim=0)
    if bool(full.any()):
        return P[:, full].mean(dim=1)
    T = P.shape[0]
    observed = (~missing).unsqueeze(-1).expand_as(P).reshape(T, -1)
    Z = torch.where(observed.reshape(P.shape), P, torch.zeros((), dtype=P.dtype, device=P.device))
    return ops.interp_linear(Z.reshape(T, -1), observed).reshape(P.shape).mean(dim=1)


def mean_distances(P: Tensor, rows: Tensor, max_frames: int = 500) -> Tensor:
    """Mean Euclidean distance over frames from each marker in ``rows`` to every marker
    ``(len(rows), J)``, on at most ``max_frames`` evenly strided frames, NaN-aware."""
    stride = max(1, P.shape[0] // max_frames)
    S = P[::stride]
    D = torch.linalg.vector_norm(S[:, rows, None] - S[:, None], dim=-1)    # (n, G, J)
    ok = torch.isfinite(D)
    return torch.where(ok, D, torch.zeros_like(D)).sum(0) / ok.sum(0).clamp(min=1)


def _pca(G: Tensor, n: int) -> tuple[Tensor, Tensor]:
    """Principal vectors (columns) and singular values of ``N / sqrt(n-1)``, descending, from the
    Gram matrix ``G = N.T @ N`` (3J x 3J: far cheaper than an SVD of the n x 3J data), in
    float64 whatever ``G``'s dtype (float32's eigh failed to converge on HDM05 bd_05-01 with
    simulated gaps: the small matrix costs nothing in double)."""
    lam, V = torch.linalg.eigh(((G + G.T) / (2 * max(n - 1, 1))).double())
    return V.flip(-1).to(G.dtype), lam.flip(-1).clamp(min=0).sqrt().to(G.dtype)


def _n_eig(s: Tensor, min_cum_sv: float) -> int:
    """Fewest leading singular values whose cumulative sum reaches ``min_cum_sv`` of the total."""
    c = torch.cumsum(s, 0)
    return int((c < min_cum_sv * c[-1]).sum()) + 1


def reconstruct(N: Tensor, Mz: Tensor, cols: Tensor, w: Tensor, min_cum_sv: float) -> Tensor:
    """Federolf (2013) Eq. 1 on one marker: training frames ``N`` (n x 3J, complete), gap frames
    ``Mz`` (m x 3J, the marker's columns ``cols`` zeroed), column weights ``w`` (3J). Returns the
    marker's columns (m x 3) reconstructed."""
    mean_N = N.mean(0)
    mean_N0 = mean_N.clone()                             # of the data with the marker zeroed
    mean_N0[cols] = 0
    std = N.std(0, unbiased=False)
    std = torch.where(std > 0, std, torch.ones_like(std))
    Nn = (N - mean_N) / std * w
    Mn = (Mz - mean_N0) / std * w
    G = Nn.T @ Nn
    G0 = G.clone()                                       # N0n = Nn with the marker's columns 0
    G0[cols] = 0
    G0[:, cols] = 0
    Vn, sn = _pca(G, N.shape[0])
    V0, s0 = _pca(G0, N.shape[0])
    k = max(_n_eig(sn, min_cum_sv), _n_eig(s0, min_cum_sv))
    Vn, V0 = Vn[:, :k], V0[:, :k]
    R = Mn @ V0 @ (Vn.T @ V0) @ Vn.T                     # Federolf 2013, Eq. 1
    return mean_N[cols] + R[:, cols] * std[cols] / w[cols]


def predict_missing_markers(P: Tensor, missing: Tensor, *, weight_scale: float, mm_weight: float,
                            distal_threshold: float, min_cum_sv: float, min_markers: int = 3,
                            fill: Tensor | None = None) -> Tensor:
    """R2 strategy on ``P`` (T, J, d), ``missing`` (T, J): every gap filled; observed kept.
    ``fill``: the missing samples to fill (default all; training rows of a stack, see
    :mod:`torchfill.solvers.session`, are left as they are and only train the bases).

    ``weight_scale`` is relative to the mean distance between markers (the original's 200 mm
    over the ~700 mm of a full-body set is 0.28). A marker whose gaps leave fewer than
    ``min_markers`` other markers to reconstruct from (the original maps from as few as one, and
    jumps by up to a metre at gap edges on real recordings) is interpolated linearly instead.

    ``auto`` asks for the same fill twice per mask (``pca_gloersen`` and ``pma``'s WPCA model):
    the last results are kept (:class:`torchfill.runtime.cache.Memo`)."""
    fill = missing if fill is None else fill
    args = (weight_scale, mm_weight, distal_threshold, min_cum_sv, min_markers)
    return _KEPT(lambda: _predict(P, missing, fill, *args), P, missing, fill, *args).clone()


#: :func:`predict_missing_markers`' last results.
_KEPT = Memo(entries=4)


def _predict(P: Tensor, missing: Tensor, fill: Tensor, weight_scale: float, mm_weight: float,
             distal_threshold: float, min_cum_sv: float, min_markers: int) -> Tensor:
    """:func:`predict_missing_markers` computed."""
    T, J, d = P.shape                       # d = 3 (markers) or 2 (image keypoints)
    out = P.clone()
    gapped = torch.nonzero(fill.any(0)).flatten()
    if len(gapped) == 0:
        return out
    c = body_centre(P, missing)
    Y = P - c[:, None]
    D = mean_distances(Y, gapped)                                          # (G, J)
    scale = weight_scale * D[D > 0].mean() if bool((D > 0).any()) else torch.ones((), dtype=P.dtype)
    lin = ops.interp_linear(torch.where(missing[..., None], 0.0, Y).reshape(T, -1),
                            (~missing).repeat_interleave(d, dim=1)).reshape(T, J, d)
    zero = torch.zeros((), dtype=P.dtype, device=P.device)
    Y0 = torch.where(torch.isfinite(Y), Y, zero)                           # the data, NaN as 0
    has_gap = fill.any(0)
    for g, i in enumerate(gapped.tolist()):
        frames = fill[:, i]
        drop = has_gap & (D[g] > distal_threshold * D[g].mean())           # distal gapped markers
        drop |= missing[frames].any(0)                                     # overlapping gaps
        drop[i] = False
        others = ~drop
        others[i] = False
        train = ~missing[:, ~drop].any(1)
        if int(train.sum()) < 2 or int(others.sum()) < min_markers:
            out[frames, i] = lin[frames, i] + c[frames]                    # too little to go on
            continue
        w = torch.exp(-D[g] ** 2 / (2 * scale ** 2))
        w[i] = mm_weight
        w = torch.where(drop, torch.ones_like(w), w).repeat_interleave(d)
        cols = torch.arange(d * i, d * i + d, device=P.device)
        Mz = torch.where(drop[None, :, None], zero, Y0[frames]).reshape(-1, J * d)
        Mz[:, cols] = 0
        N = torch.where(drop[None, :, None], zero, Y0[train]).reshape(-1, J * d)
        out[frames, i] = reconstruct(N, Mz, cols, w, min_cum_sv) + c[frames]
    return out


@register
class PCAGloersen(OneShotSolver):
    """Gløersen & Federolf (2016) PredictMissingMarkers, R2 strategy (the WPCA row of Li et al.).

    Defaults are the authors' (sigma 200 mm expressed as 0.28 of the mean inter-marker distance of
    the HDM05/CMU full-body sets, MM weight 0.02, distal threshold 0.5, 99 % of the singular values).
    One shot: ``step()`` does the whole fill.
    """

    name = "pca_gloersen"
    spatial = True
    #: fit(X, mask, training=[...]): other recordings of the same markers, in X's units, whose
    #: complete frames train the PCA bases too (see :mod:`torchfill.solvers.session`)
    fit_data = ("training",)
    params = {
        "weight_scale": Param(0.28, float, low=0.0, low_open=True,
                              doc="sigma of the distance weights, relative to the mean inter-marker distance"),
        "mm_weight": Param(0.02, float, low=0.0, low_open=True, doc="weight of the gapped marker's own columns"),
        "distal_threshold": Param(0.5, float, low=0.0,
                                  doc="gapped markers farther than this times the mean distance are dropped"),
        "min_cum_sv": Param(0.99, float, low=0.0, high=1.0, low_open=True,
                            doc="cumulative share of the singular values kept"),
    }

    def _initialize(self) -> None:
        """Nothing to set up: ``step()`` makes the whole fill (see :meth:`_estimate`)."""

    def step(self) -> dict[str, float]:
        missing = ~self.Omega_.all(dim=-1)
        P = torch.where(missing[..., None], torch.full((), float("nan"), dtype=self.M_.dtype,
                                                       device=self.M_.device), self.M_)
        train = session.training_rows(self.fit_data_.get("training", ()), self.mu_, self.sigma_)
        P_all, missing_all, todo, _ = session.stack(P, missing, train)
        self.X_ = predict_missing_markers(P_all, missing_all, fill=todo, weight_scale=self.weight_scale,
                                          mm_weight=self.mm_weight, distal_threshold=self.distal_threshold,
                                          min_cum_sv=self.min_cum_sv)[:P.shape[0]]
        return {"delta": 0.0}

    def _estimate(self) -> Tensor:
        if "X_" not in self._buffers:       # forward() before step(): the interpolation start
            self.X_ = self.interp_start()
        return self.X_
