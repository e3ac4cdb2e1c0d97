"""Tits, Tilmanne & Dutoit (2018): the individual models ``glr``, ``li``, ``lpr``, ``lgrnn`` and
their probabilistic model averaging ``pma`` (with ``pca_gloersen`` as fifth model).

The pipeline of the paper's default (MocapRecovery), rebuilt on tensors:

1. every frame is centred on the body (the never-missing markers' mean, see
   :func:`~torchfill.solvers.gloersen.body_centre`); markers are scored pairwise by how rigid their
   distance is (maximum distance + 20 x its standard deviation, the "advanced ordering");
2. markers with gaps are filled one after another, the most present first; each filled marker
   becomes available to the next ones (recursive filling);
3. a gap's local models use the three best-scored markers observed over the whole gap and at its
   borders as a local frame: LI interpolates the marker's local coordinates linearly over the gap,
   LPR (degree-2 polynomial) and LGRNN (generalized regression network, spread 0.3) regress them
   on the frame's shape (d12 and the third reference's in-plane coordinates), trained on the
   frames where all four are observed; GLR regresses the marker on every marker observed over the
   gap (global); WPCA is Gløersen & Federolf's R2 fill;
4. time constraint: each prediction gets the linear ramp that makes it meet the observed samples
   at both gap borders (one border at the ends of the recording: a constant shift);
5. model averaging: per frame, each model is weighted by the product of the kernel densities of
   its distances to the three references (densities from the observed frames), weights smoothed;
6. soft skeleton constraint: the averaged position is projected (up to 5 rounds) into the
   1 %-99 % quantile range of each reference distance;
7. filtering: references are median+mean filtered (symmetric window shrinking at gaps) before the
   local models; the filled recording is filtered once more; observed samples are put back.

Where the original fails, these do better (documented choices, observed data only):

- no never-missing marker: the original's centre is empty and nothing is filled; here the centre
  comes from linearly interpolated markers;
- markers under the original's presence threshold (30 %) are dropped and returned empty there;
  here they are kept and filled last, like any other marker;
- a gap no reference triple covers (the original leaves it empty): filled by the mean of the
  global models available (GLR, WPCA) in the averaging; by linear interpolation when none applies
  (whole-frame blackouts, and always for the standalone local models ``li``/``lpr``/``lgrnn``).
- frames are subsampled on a fixed stride, never at random; the original's 50 mm GLR weight
  threshold (which with the advanced ordering never triggers) is left out: GLR uses every marker
  observed over the gap.

References
----------
Tits M, Tilmanne J, Dutoit T (2018). Robust and automatic motion-capture data recovery using soft
skeleton constraints and model averaging. PLoS ONE 13(7): e0199744.
"""
from __future__ import annotations

import functools
from typing import ClassVar

import torch
import torch.nn.functional as F

from .. import ops
from ..runtime.cache import Memo
from .base import OneShotSolver, Param, register
from . import session
from .gloersen import body_centre, predict_missing_markers

Tensor = torch.Tensor


# -- building blocks ------------------------------------------------------------------------------
def symfilter(X: Tensor, window: int) -> Tensor:
    """Median then mean filter along time of every column of ``X`` (T x C, NaN kept), with a
    symmetric window of ``window`` frames that shrinks near gaps and ends (no delay)."""
    half = window // 2
    if half < 2:
        return X
    T = X.shape[0]
    nan = ~torch.isfinite(X)
    if bool(nan.any()):
        t = torch.arange(T, device=X.device)[:, None].expand_as(X)
        prev = torch.cummax(torch.where(nan, t, -1), dim=0).values
        nxt = T - 1 - torch.cummax(torch.where(nan, T - 1 - t, -1).flip(0), dim=0).values.flip(0)
        h = (torch.minimum(t - prev, nxt - t) - 1).clamp(max=half)  # no NaN ahead: nxt = T
    elif T < 5:
        return X                                                    # no window of 2 or more
    else:
        h = None                                                    # shrunk at the ends only
    out = X
    for reduce in ("median", "mean"):
        P = torch.nn.functional.pad(out.T[None], (half, half), value=float("nan"))[0].T
        W = P.unfold(0, 2 * half + 1, 1)                                  # (T, C, window)
        full = window_median(P, half) if reduce == "median" else W.mean(-1)
        out = _shrunk(full, out, W, h, half, reduce)
    return out


def _shrunk(full: Tensor, out: Tensor, W: Tensor, h: Tensor | None, half: int,
            reduce: str) -> Tensor:
    """:func:`symfilter`'s filtered values: ``full`` where the whole window fits, windows
    shrunk to ``2 r + 1`` rows where ``h`` (the reach, T x C; None: the distance to the ends)
    is ``r`` >= 2, ``out`` kept where it is less."""
    T = W.shape[0]
    if h is None:
        res = full.clone()
        ends = sorted({*range(min(half, T)), *range(max(T - half, 0), T)})
        res[ends] = out[ends]
    else:
        res = torch.where(h == half, full, out)
    for r in range(2, half):                                          # shrunk windows
        if h is None:
            rows = [t for t in sorted({r, T - 1 - r}) if min(t, T - 1 - t) == r]
            if rows:
                Wr = W[rows][:, :, half - r:half + r + 1].reshape(-1, 2 * r + 1).contiguous()
                v = Wr.median(-1).values if reduce == "median" else Wr.mean(-1)
                res[rows] = v.reshape(len(rows), -1)
            continue
        t_r, c_r = torch.nonzero(h == r, as_tuple=True)
        if t_r.numel():
            Wr = W[t_r, c_r, half - r:half + r + 1]
            res[t_r, c_r] = Wr.median(-1).values if reduce == "median" else Wr.mean(-1)
    return res


def window_median(P: Tensor, half: int) -> Tensor:
    """Median of every ``2 half + 1``-row window of ``P`` ((T + 2 half) x C) as ``W.median(-1)``
    of its windows, without sorting them: an odd window's median is one of its values, picked by
    a selection network of element-wise minima and maxima over the shifted rows (rows whose
    window holds a NaN come out undefined; :func:`symfilter` uses full windows only). Windows
    of other sizes fall back to ``median``."""
    T = P.shape[0] - 2 * half
    if half != 4 or P.numel() <= _NETWORK_FROM:
        return P.unfold(0, 2 * half + 1, 1).median(-1).values
    P = P.contiguous()
    p = [P[i:i + T] for i in range(9)]

    def sort2(i: int, j: int) -> None:
        p[i], p[j] = torch.minimum(p[i], p[j]), torch.maximum(p[i], p[j])

    for i, j in ((1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8)):
        sort2(i, j)                                    # each triple sorted
    p[3] = torch.maximum(p[0], p[3])                   # max of the minima
    p[5] = torch.minimum(p[5], p[8])                   # min of the maxima
    sort2(4, 7)
    p[6] = torch.maximum(p[3], p[6])
    p[4] = torch.maximum(p[1], p[4])
    p[2] = torch.minimum(p[2], p[5])
    p[4] = torch.minimum(p[4], p[7])
    sort2(4, 2)
    p[4] = torch.maximum(p[6], p[4])
    return torch.minimum(p[4], p[2])


#: Fewer values: :func:`window_median`'s network costs more than sorting the windows.
_NETWORK_FROM = 4096


def local_frame(A: Tensor, B: Tensor, C: Tensor) -> Tensor:
    """Orthonormal frame per row (T, 3, 3), columns v1 (A->B), v2 (normal of ABC), v3 = v2 x v1."""
    v1 = torch.nn.functional.normalize(B - A, dim=-1)
    v2 = torch.nn.functional.normalize(torch.cross(v1, C - A, dim=-1), dim=-1)
    v3 = torch.cross(v2, v1, dim=-1)
    return torch.stack([v1, v2, v3], dim=-1)


def to_local(P: Tensor, A: Tensor, R: Tensor) -> Tensor:
    return torch.einsum("ti,tik->tk", P - A, R)


def to_global(L: Tensor, A: Tensor, R: Tensor) -> Tensor:
    return torch.einsum("tk,tik->ti", L, R) + A


def ramp(pred: Tensor, D1: Tensor | None, D2: Tensor | None) -> Tensor:
    """Time constraint: subtract the linear ramp from the border offset ``D1`` (before the gap) to
    ``D2`` (after it) over the ``L`` gap rows of ``pred`` (L x 3); one offset held when the gap
    touches an end of the recording, none when both."""
    if D1 is None and D2 is None:
        return pred
    D1 = D2 if D1 is None else D1
    D2 = D1 if D2 is None else D2
    return pred - (D1 + (D2 - D1) * steps(pred.shape[0], pred.dtype, pred.device))


@functools.lru_cache(maxsize=256)
def steps(L: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """The ``L`` inner steps of a linear ramp, ``(1 .. L) / (L + 1)`` as a column (read only)."""
    return torch.arange(1, L + 1, dtype=dtype, device=device)[:, None] / (L + 1)


def border_offsets(pred_edge: tuple[Tensor | None, Tensor | None],
                   true_edge: tuple[Tensor | None, Tensor | None]):
    return tuple(None if p is None or q is None else p - q for p, q in zip(pred_edge, true_edge))


class Density:
    """Gaussian kernel density of ``samples``, normal-reference bandwidth ``u`` from the MAD."""

    def __init__(self, samples: Tensor):
        med = samples.median()
        sig = (samples - med).abs().median() / 0.6745
        if not bool(sig > 0):
            sig = samples.max() - samples.min()
        self.u = sig * (4.0 / (3.0 * samples.numel())) ** 0.2 if bool(sig > 0) else torch.ones_like(sig)
        self.samples, self.norm = samples.contiguous(), self.u * (2 * torch.pi) ** 0.5
        near, far = 37.3 * self.u, 38.7 * self.u       # x with a sample this far: x in [start, end]
        self.starts = torch.cat([samples - far, samples + near]).sort().values
        self.ends = torch.cat([samples - near, samples + far]).sort().values

    def __call__(self, x: Tensor) -> Tensor:
        """The density at ``x``, the bits of ``exp(-z^2 / 2).mean(1) / (u sqrt(2 pi))``. libm's
        exponential is slow (tens of times) where its result falls under the normal range:
        exponents under -700 are exponentiated only where the result is not 0."""
        z = (x[:, None] - self.samples[None]).div_(self.u)
        v = z.pow_(2).mul_(-0.5)
        if not bool(torch.isfinite(x).all()):                  # NaN stays NaN
            return v.exp_().mean(1) / self.norm
        rows = self._underflow_rows(x)
        if rows.numel():                    # exponents whose exp is not 0 (-699: or exp(-700))
            v_r = v[rows]
            t, j = ((v_r > -746.0) & (v_r <= _EXP_LOW + 1)).nonzero(as_tuple=True)
            exact = torch.exp(v_r[t, j])
        e = F.threshold_(v.clamp_(min=_EXP_LOW).exp_(), _EXP_LOW_VALUE, 0.0)   # 0 from -700 down
        if rows.numel():
            e[rows[t], j] = exact
        return e.mean(1) / self.norm

    def _underflow_rows(self, x: Tensor) -> Tensor:
        """Rows of ``x`` with a sample at 37.3 to 38.7 bandwidths (an exponent between -749 and
        -695); in every other row the kernel is either over exp(-700) or exactly 0."""
        inside = torch.searchsorted(self.starts, x, right=True) - torch.searchsorted(self.ends, x)
        return (inside > 0).nonzero().flatten()


_EXP_LOW = -700.0
_EXP_LOW_VALUE = float(torch.tensor(_EXP_LOW, dtype=torch.float64).exp())


def stride_rows(rows: Tensor, n_max: int) -> Tensor:
    """At most about ``n_max`` of the indices ``rows``, evenly strided."""
    return rows[::max(1, rows.numel() // n_max)]


def normalize(X: Tensor, rows: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """``X`` standardized by the mean and standard deviation of its ``rows`` (None: all)."""
    mu, sd = (X.mean(0), X.std(0)) if rows is None else (X[rows].mean(0), X[rows].std(0))
    sd = torch.where(sd > 0, sd, torch.ones_like(sd))
    return (X - mu) / sd, mu, sd


def poly2(X: Tensor) -> Tensor:
    """Degree-1 and degree-2 monomials of the columns of ``X`` (Tits et al.'s LPR features)."""
    n = X.shape[1]
    quad = [X[:, i] * X[:, j] for i in range(n) for j in range(i, n)]
    return torch.cat([X, torch.stack(quad, 1)], 1)


def lstsq(A: Tensor, y: Tensor) -> Tensor:
    """Minimum-norm least squares through the SVD (collinear predictors are the rule here:
    markers of one segment are affine combinations of each other; the Gram matrix loses too much
    precision for an exact fit). On the CPU LAPACK's gelsd (the same cut of singular values under
    1e-10 of the largest) solves it at half the time of forming the pseudo-inverse."""
    if A.device.type == "cpu":
        return torch.linalg.lstsq(A, y, rcond=1e-10, driver="gelsd").solution
    return torch.linalg.pinv(A, rtol=1e-10) @ y


def grnn(Xtr: Tensor, Ytr: Tensor, X: Tensor, spread: float) -> Tensor:
    """Generalized regression network (MATLAB newgrnn/sim): kernel-weighted mean of ``Ytr``."""
    b2 = torch.log(torch.tensor(2.0, dtype=X.dtype)) / spread ** 2
    A = torch.cdist(X, Xtr).pow_(2).mul_(-b2).exp_()
    s = A.sum(1, keepdim=True)
    return torch.where(s > 0, A @ Ytr / s.clamp(min=1e-300), Ytr.mean(0).expand(X.shape[0], -1))


def space_constraint(P: Tensor, refs: list[Tensor], ranges, rounds: int = 5) -> Tensor:
    """Soft skeleton constraint: move each row of ``P`` along the line to each reference (third,
    second, first) into that distance's range (``ranges``: a (min, max) pair per reference),
    ``rounds`` times (fewer once a round moves nothing: the next would not either)."""
    ranges = [(float(r), float(R)) for r, R in ranges]
    for _ in range(rounds):
        moved = False
        for Q, (r, R) in zip(reversed(refs), reversed(ranges)):
            v = P - Q
            d = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
            target = d.clamp(min=r, max=R)
            move = (d > 0) & (target != d)
            if bool(move.any()):
                P = torch.where(move, Q + v / d.clamp(min=1e-300) * target, P)
                moved = True
        if not moved:
            break
    return P


def rigidity(Y: Tensor, missing: Tensor, max_frames: int = 1000) -> Tensor:
    """Pairwise score (J x J): max distance + 20 x distance standard deviation, over frames where
    both markers are observed (self: inf). Lower = more rigidly linked. ``auto``'s ``li``,
    ``lgrnn`` and ``pma`` ask for the same one: the last results are kept."""
    return _KEPT_SCORE(lambda: _rigidity(Y, missing, max_frames), Y, missing, max_frames)


def _rigidity(Y: Tensor, missing: Tensor, max_frames: int) -> Tensor:
    rows = stride_rows(torch.arange(Y.shape[0], device=Y.device), max_frames)
    S, ok = torch.nan_to_num(Y[rows]), ~missing[rows]
    D = torch.cdist(S, S, compute_mode="donot_use_mm_for_euclid_dist")  # finite: masks multiply
    both = ok[:, :, None] & ok[:, None]
    w = both.to(D.dtype)
    count = w.sum(0)
    n = count.clamp(min=2)
    Dz = D * w
    mean = Dz.sum(0) / n
    std = (((D - mean) * w) ** 2).sum(0).div(n - 1).sqrt()
    dmax = Dz.masked_fill_(~both, -1.0).amax(0)
    score = dmax + 20 * std
    score = torch.where(count >= 2, score, torch.full_like(score, float("inf")))
    return score.fill_diagonal_(float("inf"))


#: The last results of :func:`rigidity`, of the reference tracks' filter (one marker's track
#: before its gaps are filled is the same in ``li``, ``lgrnn`` and ``pma``) and of
#: :func:`local_geometry`.
_KEPT_SCORE = Memo(entries=4)
_KEPT_TRACK = Memo(entries=512)
_KEPT_FRAME = Memo(entries=64)


# -- the models -----------------------------------------------------------------------------------
class _Local:
    """One reference triple's local frame and its trained models (LPR, LGRNN) for marker ``k``."""

    def __init__(self, Y: Tensor, k: int, triple: tuple[int, int, int], filtered,
                 smooth: float, models: set[str], T: int | None = None):
        tracks = [filtered(j) for j in (k, *triple)]
        self.T = Y.shape[0] if T is None else T          # the recording's rows (then training)
        self.raw = [Y[:, j] for j in triple]
        self.p1 = tracks[1]
        self.R, self.p0p, X, rows, ranges, self.samples = _KEPT_FRAME(
            lambda: local_geometry(*tracks), *tracks)
        self.ok = rows.numel() >= 3
        if not self.ok:
            return
        if models & {"lpr", "lgrnn"}:                    # the regressions (``li`` has none)
            self._train(X, rows, models)
        self.smooth = smooth
        self.ranges = ranges.tolist()
        self._densities: list[Density] | None = None

    def _train(self, X: Tensor, rows: Tensor, models: set[str]) -> None:
        """LPR's coefficients and LGRNN's training pairs on the frame-shape features ``X``."""
        tr = stride_rows(rows, 1000)
        Xl, _, _ = normalize(X, rows)
        Xp, _, _ = normalize(poly2(X), rows)
        self.Xl = torch.cat([torch.ones_like(X[:, :1]), Xl], 1)
        self.Xp = torch.cat([torch.ones_like(X[:, :1]), Xp], 1)
        Yn, self.mu, self.sd = normalize(self.p0p[tr])
        if "lpr" in models:
            self.beta = lstsq(self.Xp[tr], Yn)
        if "lgrnn" in models:
            self.train = (self.Xl[tr, 1:], Yn)

    def _interpolate(self, a: int, b: int) -> Tensor:
        """LI: marker k's local coordinates interpolated linearly over the gap rows [a, b) (the
        observed border held at an end of the recording), as :func:`ops.interp_linear`."""
        T, L = self.T, b - a
        edges = self.p0p[[i for i in (a - 1, b) if 0 <= i < T]]
        if edges.shape[0] == 0 or not bool(torch.isfinite(edges).all()):
            lo, hi = max(a - 1, 0), min(b + 1, T)
            return ops.interp_linear(torch.nan_to_num(self.p0p[lo:hi]),
                                     torch.isfinite(self.p0p[lo:hi]))[a - lo:a - lo + L]
        if edges.shape[0] == 1:
            return edges.expand(L, -1)
        return edges[0] + steps(L, edges.dtype, edges.device) * (edges[1] - edges[0])

    def densities(self) -> list[Density]:
        """The reference distances' densities (from the observed frames), made once."""
        if self._densities is None:
            self._densities = [Density(s) for s in self.samples]
        return self._densities

    def _edges(self, a: int, b: int):
        T = self.T
        return (self.p0p[a - 1] if a > 0 else None, self.p0p[b] if b < T else None)

    def predict(self, model: str, a: int, b: int) -> Tensor:
        """Gap rows [a, b) of marker k in global (centred) coordinates by one local model."""
        T = self.T
        lo, hi = max(a - 1, 0), min(b + 1, T)
        if model == "li":
            L = self._interpolate(a, b)
        else:
            if model == "lpr":
                pred = self.Xp[lo:hi] @ self.beta
            else:
                pred = grnn(*self.train, self.Xl[lo:hi, 1:], self.smooth)
            pred = pred * self.sd + self.mu
            inner = pred[a - lo:a - lo + b - a]
            edges_pred = (pred[0] if a > 0 else None, pred[-1] if b < T else None)
            L = ramp(inner, *border_offsets(edges_pred, self._edges(a, b)))
        return to_global(L, self.p1[a:b], self.R[a:b])


def local_geometry(p0: Tensor, p1: Tensor, p2: Tensor, p3: Tensor):
    """The local frame ``R`` of the references ``p1, p2, p3`` (T, 3 each), the marker ``p0`` in
    it, the frame-shape features ``X`` (d12 and p3's in-plane coordinates), the rows where both
    are finite, and from the observed frames the ranges (1 %, 99 %) and density samples of the
    marker's distance to each reference. ``li``, ``lgrnn`` and ``pma`` of one round ask for the
    same ones: the last results are kept."""
    R = local_frame(p1, p2, p3)
    p0p = to_local(p0, p1, R)
    p3p = to_local(p3, p1, R)
    X = torch.stack([torch.linalg.vector_norm(p1 - p2, dim=-1), p3p[:, 0], p3p[:, 2]], 1)
    rows = torch.nonzero(torch.isfinite(p0p).all(1) & torch.isfinite(X).all(1)).flatten()
    if rows.numel() < 3:
        return R, p0p, X, rows, None, None
    dist = [torch.linalg.vector_norm(q - p0, dim=-1) for q in (p1, p2, p3)]
    dist = [d[torch.isfinite(d)] for d in dist]
    q = torch.tensor([0.01, 0.99], dtype=p0.dtype, device=p0.device)
    ranges = torch.stack([torch.quantile(d, q) for d in dist])
    return R, p0p, X, rows, ranges, [stride_rows(d, 200) for d in dist]   # the paper: 200 suffice


def glr_fill(Y: Tensor, missing: Tensor, k: int, a: int, b: int, cache: dict,
             T: int | None = None, seen: Tensor | None = None) -> Tensor | None:
    """Global linear regression of marker ``k`` on every marker observed over [a-1, b] (Tits et
    al. model 4), with the time constraint; None with fewer than 4 such markers. ``T``: the
    recording's rows when training rows follow them (they train the regression only); ``seen``:
    the markers observed over [a-1, b] when known."""
    T = Y.shape[0] if T is None else T
    lo, hi = max(a - 1, 0), min(b + 1, T)
    refs = ~missing[lo:hi].any(0) if seen is None else seen.clone()
    refs[k] = False
    if int(refs.sum()) < 4:
        return None
    key = tuple(torch.nonzero(refs).flatten().tolist())
    if key not in cache:
        rows = torch.nonzero(~missing[:, k] & ~missing[:, refs].any(1)).flatten()
        if rows.numel() < 4:
            return None
        tr = stride_rows(rows, 500)
        Yr = Y[tr]                                       # the training rows only
        X = torch.cat([torch.ones_like(Yr[:, 0, :1]), Yr[:, refs].reshape(tr.numel(), -1)], 1)
        Yn, mu, sd = normalize(Y[tr, k])
        cache[key] = (lstsq(X, Yn), mu, sd)
    beta, mu, sd = cache[key]
    X = torch.cat([torch.ones_like(Y[lo:hi, 0, :1]), Y[lo:hi][:, refs].reshape(hi - lo, -1)], 1)
    pred = X @ beta * sd + mu
    edges = (pred[0] if a > 0 else None, pred[-1] if b < T else None)
    truth = (Y[a - 1, k] if a > 0 else None, Y[b, k] if b < T else None)
    return ramp(pred[a - lo:a - lo + b - a], *border_offsets(edges, truth))


def wpca_fill(W: Tensor, Y: Tensor, k: int, a: int, b: int, T: int | None = None) -> Tensor:
    """Gløersen fill of the gap with the time constraint (offsets against the first/last row)."""
    T = Y.shape[0] if T is None else T
    pred = W[a:b, k]
    D1 = pred[0] - Y[a - 1, k] if a > 0 else None
    D2 = pred[-1] - Y[b, k] if b < T else None
    return ramp(pred, D1, D2)


def average(preds: list[Tensor], local: _Local, a: int, b: int, window: int) -> Tensor:
    """Model averaging (Tits et al.): per frame, weights = product of the reference-distance
    densities, smoothed along the gap; then the weighted mean."""
    if len(preds) == 1:
        return preds[0]
    L, m = b - a, len(preds)
    Ps = symfilter(torch.stack(preds, 1).reshape(L, 3 * m), window).reshape(L, m, 3)
    w = None                                             # the product of the densities
    for Q, density in zip(local.raw, local.densities()):
        f = density(torch.linalg.vector_norm(Ps - Q[a:b, None], dim=-1).reshape(-1)).reshape(L, m)
        w = f if w is None else w * f
    w = symfilter(ops.clamp_tiny(w, 1e-200), min(window, (L + 1) // 2))     # > 0 in float32 too
    return (w[..., None] * Ps).sum(1) / w.sum(1)[:, None]


def tits_fill(P: Tensor, missing: Tensor, models: set[str], *, window: int, smooth: float,
              wpca: dict, space: bool, train: list[Tensor] = ()) -> Tensor:
    """The Tits et al. pipeline on ``P`` (T, J, 3; NaN where ``missing``) with ``models``;
    ``window`` < 4 frames: no filtering anywhere. ``train``: other recordings of the same markers
    (T_i, J, 3; NaN where not observed, in ``P``'s units) whose frames train the models too
    (see :mod:`torchfill.solvers.session`); only ``P``'s gaps are filled."""
    T0 = P.shape[0]
    P, missing, todo, pieces = session.stack(P, missing, train)
    T, J, _ = P.shape
    c = body_centre(P, missing)
    Y = P - c[:, None]
    miss = missing.clone()
    W = None
    if "wpca" in models:
        W = predict_missing_markers(P, missing, fill=todo, **wpca) - c[:, None]
    local_models = models & {"li", "lpr", "lgrnn"}
    score = rigidity(Y, missing) if local_models else None
    presence = (~missing).sum(0)
    gapped = [k for k in torch.argsort(presence, descending=True, stable=True).tolist()
              if bool(todo[:, k].any()) and bool((~missing[:, k]).any())]
    cache: dict[int, Tensor] = {}
    rest: list[Tensor] = []                              # the training rows, filtered once

    def filtered(j: int) -> Tensor:
        """Marker ``j`` filtered along time (recomputed once it has been filled; the training
        rows, never filled, are filtered once for every marker)."""
        if j not in cache:
            if not rest:
                rest.append(training_tracks(Y[T0:], [(a - T0, b - T0) for a, b in pieces[1:]],
                                            window))
            y = Y[:T0, j]
            cache[j] = torch.cat([_KEPT_TRACK(lambda: symfilter(y.clone(), window), y, window),
                                  rest[0][:, j]])
        return cache[j]

    for k in gapped:
        if local_models:
            order, scored = torch.argsort(score[k]).tolist(), torch.isfinite(score[k])
            filtered(k)                                  # as it was before its gaps are filled
        glr_cache, local_cache = {}, {}
        for _, a, b in ops.runs(todo[:T0, k:k + 1]):
            lo, hi = max(a - 1, 0), min(b + 1, T0)
            preds, local, valid = [], None, []
            seen = ~miss[lo:hi].any(0)
            if local_models:
                present = (seen & scored).tolist()
                valid = [r for r in order if r != k and present[r]]
            if len(valid) >= 3:
                triple = tuple(valid[:3])
                if triple not in local_cache:
                    local_cache[triple] = _Local(Y, k, triple, filtered, smooth, models, T0)
                local = local_cache[triple]
                if local.ok:
                    preds += [local.predict(m, a, b) for m in ("li", "lpr", "lgrnn") if m in models]
                else:
                    local = None
            g = glr_fill(Y, miss, k, a, b, glr_cache, T0, seen) if "glr" in models else None
            glob = [] if g is None else [g]
            if W is not None:
                glob.append(wpca_fill(W, Y, k, a, b, T0))
            if local is not None:
                fill = average(preds + glob, local, a, b, window)
                if space:
                    fill = space_constraint(fill, [q[a:b] for q in local.raw], local.ranges)
            elif glob:
                fill = torch.stack(glob).mean(0)
            else:
                continue
            Y[a:b, k] = fill
            miss[a:b, k] = False
        cache.pop(k, None)
    Y, miss, c, P, missing = Y[:T0], miss[:T0], c[:T0], P[:T0], missing[:T0]
    rest = miss.unsqueeze(-1).expand_as(Y).reshape(T0, -1)
    Y = ops.interp_linear(torch.nan_to_num(Y).reshape(T0, -1), ~rest).reshape(T0, J, 3)
    out = (Y + c[:, None]).reshape(T0, -1)
    cols = missing.repeat_interleave(3, dim=1).any(0)      # filtered columns are independent:
    out[:, cols] = symfilter(out[:, cols], window)           # only those with a gap are kept
    return torch.where(missing[..., None], out.reshape(T0, J, 3), P)


def training_tracks(Y: Tensor, pieces: list[tuple[int, int]], window: int) -> Tensor:
    """The training rows ``Y`` (T, J, 3) filtered along time piece by piece; the twins of one
    hold-out round (``li``, ``pma``) stack the same rows: the last results are kept."""
    if Y.shape[0] == 0:
        return Y
    flat = Y.reshape(Y.shape[0], -1)
    return _KEPT_REST(lambda: session.piecewise(lambda y: symfilter(y, window), flat, pieces),
                      flat, pieces, window).reshape(Y.shape)


_KEPT_REST = Memo(entries=2)


class _Tits(OneShotSolver):
    """Common frame of the Tits et al. (2018) solvers; ``models`` picks which take part."""

    spatial = True
    #: fit(X, mask, training=[...]): other recordings of the same markers, in X's units, whose
    #: frames train the models too (see :mod:`torchfill.solvers.session`)
    fit_data = ("training",)
    models: ClassVar[frozenset[str]] = frozenset()
    params = {
        "window": Param(9, int, low=1, doc="filter window in frames (the paper's 0.07 s at 120 Hz)"),
        "smooth": Param(0.3, float, low=0.0, low_open=True, doc="GRNN spread on normalized features"),
        "space_constraint": Param(True, bool, doc="soft skeleton (reference distance) constraint"),
        "filtering": Param(True, bool, doc="median+mean filter of references and of the filled output"),
    }

    def _initialize(self) -> None:
        self.require_3d("the local models work in the frame of three markers")

    def step(self) -> dict[str, float]:
        missing = ~self.Omega_.all(dim=-1)
        P = torch.where(missing[..., None], torch.full((), float("nan"), dtype=self.M_.dtype,
                                                       device=self.M_.device), self.M_)
        wpca = dict(weight_scale=0.28, mm_weight=0.02, distal_threshold=0.5, min_cum_sv=0.99)
        train = session.training_rows(self.fit_data_.get("training", ()), self.mu_, self.sigma_)
        self.X_ = tits_fill(P, missing, set(self.models), window=self.window if self.filtering else 1,
                            smooth=self.smooth, wpca=wpca, space=self.space_constraint, train=train)
        return {"delta": 0.0}

    def _estimate(self) -> Tensor:
        if "X_" not in self._buffers:       # forward() before step(): the interpolation start
            self.X_ = self.interp_start()
        return self.X_


@register
class GLR(_Tits):
    """Global linear regression on every marker observed over the gap (Tits et al. model 4)."""

    name = "glr"
    models = frozenset({"glr"})


@register
class LI(_Tits):
    """Local interpolation in the frame of the three most rigidly linked markers (model 1)."""

    name = "li"
    models = frozenset({"li"})


@register
class LPR(_Tits):
    """Local polynomial (degree 2) regression in the reference frame (model 2)."""

    name = "lpr"
    models = frozenset({"lpr"})


@register
class LGRNN(_Tits):
    """Local generalized regression neural network in the reference frame (model 3)."""

    name = "lgrnn"
    models = frozenset({"lgrnn"})


@register
class PMA(_Tits):
    """Probabilistic model averaging of LI, LPR, LGRNN, GLR and WPCA (Tits et al. 2018), with the
    soft skeleton constraint, time constraint and filtering of their default pipeline."""

    name = "pma"
    models = frozenset({"li", "lpr", "lgrnn", "glr", "wpca"})
