"""PCA gap filling from a training set of complete motion (Li, Yu, Kieu, Vuong & Zhang 2020).

Two one-shot solvers (``step()`` does the whole fill, like the interpolation baselines):

* ``pca_train`` (Eq. 1-4, and Eq. 5-8 with ``layout="horizontal"``): the gaps of a recording are
  estimated from a principal eigenspace learned on complete training frames, through a linear
  transformation ``T`` from the eigenspace of the *gapped* data (the gap template applied to the
  training data) to the eigenspace of the complete data.
* ``pca_blackout`` (Eq. 9-16): whole frames missing. A temporal eigenspace ``V`` is learned on
  training pieces of the length of a window around the blackout; its rows split into observed
  (``V~``) and missing (``V^``) frames and the missing rows are a weighted least-squares
  prediction, ``B^ = V^ (V~' W V~)^-1 V~' W B~`` (Eq. 16).

Training data
-------------
The hyperparameter ``training`` is a list of arrays/tensors ``(T_i, J, D)`` whose markers are those
of the data given to ``fit`` (same J, same order; ``torchfill.fill`` aligns MarkerSequences by
label). Only complete frames (every marker observed) are used. ``training=None`` uses the complete
frames (complete stretches, for the temporal eigenspace) of the recording itself: the paper's
"long motion sequence" scenario. The training data are put in the units of the data by the same
normalization as the data (``(A - mu_) / sigma_``).

Reading of the paper, and where we depart from the printed equations
--------------------------------------------------------------------
* The printed Eq. 3 is garbled in our copy. We solve Eq. 2, ``A_i U = A_i(0) U(0) T`` over all
  pieces, in the least-squares sense, and derived the normal equations ourselves:
  ``(sum_i P_i' P_i) T = sum_i P_i' A_i U`` with ``P_i = A_i(0) U(0)``. Because ``U(0)`` holds
  eigenvectors of ``sum_i A_i(0)' A_i(0)``, ``sum_i P_i' P_i`` is the diagonal matrix of their
  eigenvalues and ``T = Lambda(0)^-1 U(0)' D C U`` (``C`` the training covariance, ``D`` the 0/1
  template of the observed coordinates), so no piece needs to be formed explicitly.
* The paper gives each piece its own ``U_i(0)``. Eigenvectors are defined only up to sign (and a
  rotation inside repeated eigenvalues), so one ``T`` cannot map differently signed bases; we use
  the eigenspace of all gapped pieces together, the same ``U(0)`` for every piece and for ``B``.
* The template of a test frame is its set of observed markers. Spatial PCA does not depend on where
  a frame sits inside its piece, so instead of one ``T`` for the whole T x 3J template we solve one
  ``T`` per distinct frame template (the frames of ``B`` grouped by which markers they miss), each
  from *all* training frames with that template. This is what makes the fill exact on data lying
  in an r-dimensional subspace (tests), and is never worse-posed than the single ``T``.
* Eq. 5-8 (pieces from different sources concatenated horizontally, ``A = [A_1 ... A_n]``): the
  eigenvectors of ``A A'`` form a *temporal* basis of the trajectories of length ``L``; we fill each
  marker's gap from the observed frames of its own three coordinates in a window around the gap,
  with the estimator of Eq. 16 (``layout="horizontal"``).

* Eq. 16 as printed is a plain weighted least-squares fit of the temporal basis to the observed
  frames. On real recordings it blows up on long blackouts (hundreds of mm at 30-40 % missing),
  so by default (``prior=True``) the coefficients get the probabilistic-PCA prior of Tipping &
  Bishop (their variances are the eigenvalues, the noise variance is the mean discarded
  eigenvalue): ``V^ (V~' W V~ + sigma^2 Lambda^-1)^-1 V~' W B~``. It vanishes on exactly low-rank
  data, where Eq. 16 is recovered; ``prior=False`` is the paper's estimator.
* With a training set, ``pca_train`` also mixes the recording's own complete frames (when it has
  any) into the training moments with the share ``self_share`` of the weight: training and test
  subjects differ in body size and marker placement, and this adapts the eigenspace to the
  subject.

Translation. Markers sit at absolute positions in the room, and training and test recordings are
in different places. With ``centre=True`` (default) every frame is expressed relative to the
centroid of the markers observed in it (body-centred coordinates, a linear map per template) and
the centroid is added back; measured on cross-recording fills in ``experiments/results/pca.md``.

Eigenspaces are computed once per training set: the spatial second moments (``n, sum a, sum a'a``)
and the temporal bases (per window length) are cached at module level, keyed on a hash of the
training data's bytes, so repeated fills with the same training set reuse them.

References
----------
Z. Li, H. Yu, H. D. Kieu, T. L. Vuong, J. J. Zhang, "PCA-based robust motion data recovery",
IEEE Access 8, 76980-76990 (2020), doi:10.1109/ACCESS.2020.2989744.
"""
from __future__ import annotations

import hashlib
import warnings

import torch

from .. import ops
from ..runtime.cache import Memo
from .base import OneShotSolver, Param, _deprecated, register

Tensor = torch.Tensor

_KEPT = Memo(16)               # training eigenspaces, by the training's fingerprint


# -- small pure helpers ------------------------------------------------------------------------
def explained_rank(eigvals: Tensor, variance: float) -> int:
    """Smallest r whose leading eigenvalues explain at least ``variance`` of the total.

    ``eigvals`` are in descending order; negative round-off is clipped to zero.
    """
    lam = eigvals.clamp(min=0)
    total = lam.sum()
    if float(total) <= 0:
        return 1
    cum = torch.cumsum(lam, 0) / total
    target = torch.tensor(variance * (1 - 1e-12), dtype=cum.dtype, device=cum.device)
    r = int(torch.searchsorted(cum, target).item()) + 1
    return max(1, min(r, int((lam > lam[0] * 1e-12).sum())))


def _eigh_desc(C: Tensor) -> tuple[Tensor, Tensor]:
    """Eigenvalues (descending) and eigenvectors of a symmetric matrix (batched)."""
    lam, U = torch.linalg.eigh((C + C.transpose(-1, -2)) / 2)
    return lam.flip(-1), U.flip(-1)


def complete_runs(item: Tensor) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of complete frames (all markers finite) of a ``(T, J, 3)``."""
    ok = torch.isfinite(item).reshape(item.shape[0], -1).all(dim=1)
    return [(a, b) for _, a, b in ops.runs(ok[:, None])]


def check_training(training, J: int, owner: str, *, dtype, device, D: int = 3) -> list[Tensor]:
    """Training items as tensors ``(T_i, J, D)`` of the data's dtype/device; expected vs found."""
    items = []
    for i, item in enumerate(training):
        item = torch.as_tensor(item)
        if item.ndim != 3 or item.shape[1:] != (J, D):
            raise ValueError(f"{owner}: training[{i}] expected shape (T, {J}, {D}) (the markers of "
                             f"the data, in the same order), found {tuple(item.shape)}")
        items.append(item.to(dtype=dtype, device=device))
    if not items:
        raise ValueError(f"{owner}: training expected a non-empty list of (T, {J}, {D}) arrays, "
                         "found []")
    return items


def _fingerprint(items: list[Tensor]) -> str:
    h = hashlib.blake2b(digest_size=16)
    for item in items:
        h.update(str((tuple(item.shape), item.dtype)).encode())
        h.update(item.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _cached(key: tuple, make):
    """``make()``, or its result kept for ``key`` (cleared with the runtime's cache)."""
    return _KEPT(make, *key)


# -- spatial eigenspace (Eq. 1-4) --------------------------------------------------------------
def spatial_moments(rows: Tensor) -> tuple[int, Tensor, Tensor]:
    """``(n, sum_t a_t, sum_t a_t' a_t)`` of complete frames ``rows`` (n x 3J)."""
    return rows.shape[0], rows.sum(dim=0), rows.T @ rows


def centring_map(observed: Tensor, centre: bool, D: int = 3) -> Tensor:
    """``L`` (DJ x DJ): ``x L`` subtracts from every marker the centroid of the observed markers.

    ``observed`` is a bool (J,); ``D`` the coordinates per marker. With ``centre=False`` the identity.
    """
    J = observed.shape[0]
    dtype = torch.float64 if not observed.is_floating_point() else observed.dtype
    eye = torch.eye(D * J, dtype=dtype, device=observed.device)
    if not centre:
        return eye
    o = observed.to(dtype) / observed.sum().clamp(min=1)
    E = torch.kron(torch.outer(o, torch.ones(J, dtype=dtype, device=observed.device)),
                   torch.eye(D, dtype=dtype, device=observed.device))
    return eye - E


def template_operator(n: int, s: Tensor, S: Tensor, observed: Tensor, *, variance: float,
                      rank: int | None, centre: bool, rtol: float = 1e-10):
    """For one frame template (``observed`` markers), the pieces of Eq. 4.

    Returns ``(L, m, K)`` such that a frame ``b`` (zeros where missing) is estimated by
    ``b^ = ((b L - m) D) K + m + b (I - L)``: ``L`` body-centres on the observed markers, ``m`` is
    the training mean in those coordinates, ``K = U(0) T U'`` (Eq. 4), ``D`` the template.
    """
    D = S.shape[0] // observed.shape[0]                            # coordinates per marker
    L = centring_map(observed, centre, D).to(S.dtype)
    m = (s @ L) / n
    C = L.T @ S @ L / n - torch.outer(m, m)                       # covariance of A L
    lam, U = _eigh_desc(C)
    r = rank if rank is not None else explained_rank(lam, variance)
    U = U[:, :min(r, U.shape[1])]                                  # common eigenspace U
    d = observed.repeat_interleave(D).to(S.dtype)                  # diagonal of D
    C0 = d[:, None] * C * d[None, :]                               # covariance of A(0) = A L D
    lam0, U0 = _eigh_desc(C0)
    r0 = min(U.shape[1], int((lam0 > rtol * lam0[0].clamp(min=1e-300)).sum()))
    if r0 == 0 or not bool(lam0[0] > 0):
        # the observed coordinates vary not at all once centred (one observed marker, body-
        # centred): they say nothing beyond the centroid, so the estimate is the mean template
        return L, m, torch.zeros_like(C)
    lam0, U0 = lam0[:r0], U0[:, :r0]                               # gapped eigenspace U(0)
    # Eq. 2-3, normal equations (derived; the printed Eq. 3 is garbled in our copy):
    #   (sum P_i'P_i) T = sum P_i' A_i U,  P_i = A_i(0) U(0)  =>  T = Lambda0^-1 U(0)' D C U
    T = (U0.T @ (d[:, None] * C) @ U) / lam0[:, None]
    K = U0 @ T @ U.T                                               # Eq. 4: B* = B(0) U(0) T U'
    return L, m, K


def spatial_fill(Y: Tensor, missing: Tensor, n: int, s: Tensor, S: Tensor, *, variance: float,
                 rank: int | None, centre: bool) -> Tensor:
    """Fill the frames of ``Y`` (T x 3J, zeros where missing) that have some but not all markers
    missing (``missing`` is a bool (T, J)), one transformation per distinct frame template."""
    out = Y.clone()
    partial = missing.any(dim=1) & ~missing.all(dim=1)
    if not bool(partial.any()):
        return out
    rows = torch.nonzero(partial).flatten()
    templates, inverse = torch.unique(missing[rows], dim=0, return_inverse=True)
    for g in range(templates.shape[0]):
        observed = ~templates[g]
        L, m, K = template_operator(n, s, S, observed, variance=variance, rank=rank, centre=centre)
        idx = rows[inverse == g]
        b = Y[idx]
        d = observed.repeat_interleave(Y.shape[1] // observed.shape[0]).to(Y.dtype)
        est = ((b @ L - m) * d) @ K + m + (b - b @ L)             # Eq. 4, centroid added back
        out[idx] = torch.where(d.bool(), b, est)
    return out


# -- temporal eigenspace (Eq. 5-16) ------------------------------------------------------------
def temporal_basis(pieces_source: list[Tensor], length: int, stride: int, variance: float,
                   rank: int | None) -> tuple[Tensor, Tensor]:
    """Orthonormal temporal basis ``[1/sqrt(L), V]`` (L x (r+1)) from training pieces of length L,
    and the probabilistic-PCA prior precision of each basis coefficient.

    ``pieces_source`` are complete stretches (n_i x 3J). Every window of ``length`` frames at
    ``stride`` is a piece ``A_i``; pieces are concatenated horizontally, ``A = [A_1 ... A_n]``
    (Eq. 5 / 9), each column centred on its mean (trajectories relative to their mean position),
    and ``V`` holds the leading eigenvectors of ``A A'`` (Eq. 10). The constant vector is added to
    the basis so that the (unknown) mean of a test trajectory is estimated with the rest.

    The prior (Tipping & Bishop's probabilistic PCA): coefficient k ~ N(0, lambda_k), residual
    noise variance sigma^2 = mean of the discarded eigenvalues (all per column); the returned
    precision is ``sigma^2 / lambda_k`` (0 for the constant). It is 0 when the training data has
    rank r exactly, so Eq. 16 is then recovered unchanged.
    """
    dtype, device = pieces_source[0].dtype, pieces_source[0].device
    G = torch.zeros(length, length, dtype=dtype, device=device)
    cols = 0
    for src in pieces_source:
        if src.shape[0] < length:
            continue
        P = src.unfold(0, length, stride)                          # (n_pieces, 3J, L)
        P = P - P.mean(dim=2, keepdim=True)
        P = P.reshape(-1, length)
        G += P.T @ P                                               # A A'
        cols += P.shape[0]
    lam, V = _eigh_desc(G)
    lam = lam.clamp(min=0) / max(cols, 1)                          # per-column covariance spectrum
    r = rank if rank is not None else explained_rank(lam, variance)
    r = min(r, length - 1)
    sigma2 = lam[r:length - 1].sum() / max(length - 1 - r, 1)
    one = torch.full((length, 1), length ** -0.5, dtype=dtype, device=device)
    prec = torch.cat([torch.zeros(1, dtype=dtype, device=device),
                      sigma2 / lam[:r].clamp(min=torch.finfo(dtype).tiny)])
    return torch.cat([one, V[:, :r]], dim=1), prec


def edge_weights(missing: Tensor, scale: float | None) -> Tensor:
    """Diagonal of W (Eq. 13-16): ``exp(-d / (scale * m))``, d the distance in frames to the nearest
    missing frame and m the number of missing frames; ``scale=None`` gives W = I."""
    L = missing.shape[0]
    dtype = torch.float64
    if scale is None or not bool(missing.any()):
        return torch.ones(L, dtype=dtype, device=missing.device)
    t = torch.arange(L, device=missing.device, dtype=dtype)
    gaps = t[missing]
    d = (t[:, None] - gaps[None, :]).abs().min(dim=1).values
    return torch.exp(-d / (scale * max(int(missing.sum()), 1)))


def temporal_estimate(V: Tensor, Y: Tensor, observed: Tensor, w: Tensor,
                      prec: Tensor | None = None) -> Tensor:
    """Eq. 16: rows of ``Y`` (L x c) at unobserved frames from the observed ones,
    ``Y^ = V^ (V~' W V~ + P)^-1 V~' W Y~``, with ``P = diag(prec)`` the probabilistic-PCA prior
    (``None`` or zeros: the paper's estimator). ``w`` is scaled to max 1 (a precision relative to
    the noise of the prior)."""
    Vo, Vm = V[observed], V[~observed]                             # V~ (observed), V^ (missing)
    wo = (w[observed] / w[observed].max()).to(V.dtype)
    A = Vo.T @ (wo[:, None] * Vo)                                  # V~' W V~   (Eq. 15)
    rhs = Vo.T @ (wo[:, None] * Y[observed])                       # V~' W B~
    if prec is not None:
        A = A + torch.diag(prec.to(V.dtype))
    if A.device.type == "cpu":
        coef = torch.linalg.lstsq(A, rhs).solution                 # rank-revealing (gelsy)
    else:                                                          # CUDA lstsq assumes full rank
        coef = torch.linalg.pinv(A, hermitian=True) @ rhs
    out = Y.clone()
    out[~observed] = Vm @ coef                                     # Eq. 16
    return out


def window(a: int, b: int, T: int, length: int) -> tuple[int, int]:
    """A window of ``length`` frames around the run ``[a, b)``, inside ``[0, T)``."""
    length = min(length, T)
    start = min(max(0, a - (length - (b - a)) // 2), T - length)
    return start, start + length


# -- solvers -----------------------------------------------------------------------------------
class _PCA(OneShotSolver):
    """Shared set-up: training data in normalized units, complete frames, cached statistics."""

    params = {
        "training": Param(None, (list, tuple), allow_none=True,
                          doc="deprecated (one release): pass the training data to "
                              "fit(X, mask, training=...) or torchfill.fill(..., training=...)"),
        "energy": Param(0.9999, float, low=0.0, high=1.0, low_open=True,
                        doc="rank r = fewest eigenvectors explaining this share of the training "
                            "variance, i.e. of the energy (0.9999: chosen among 0.99-0.99999 on the development "
                            "recordings cmu_85_02 and HDM_bd_01-02, experiments/pca_dev.yaml)"),
        "rank": Param(None, int, low=1, allow_none=True, doc="fixed rank r instead of the rule"),
        "self_share": Param(0.5, float, low=0.0, high=1.0,
                            doc="with a training set: weight of the recording's own complete frames "
                                "in the spatial moments (0 = training only; 0.5: best of 0-0.5 on the "
                                "development recordings)"),
        "prior": Param(True, bool, doc="temporal eigenspace (Eq. 16): add the probabilistic-PCA "
                                       "prior of the coefficients (False: the paper's plain "
                                       "least squares)"),
    }
    #: one name per idea: the share of the spectrum kept is ``energy`` in every solver
    renamed = {"variance": "energy"}

    def _self_data(self) -> Tensor:
        """The recording itself, normalized, NaN where missing (for ``training=None``)."""
        return torch.where(self.Omega_, self.M_, torch.full_like(self.M_, float("nan")))

    def _spatial_stats(self) -> tuple[int, Tensor, Tensor]:
        """Moments of the complete training frames in normalized units (cached per training set)."""
        J = self.M_.shape[1]
        items = self.training_items_
        if items is None:
            D = self._self_data().reshape(self.M_.shape[0], -1)
            n, s, S = spatial_moments(D[torch.isfinite(D).all(dim=1)])
            where = "the recording itself (training=None)"
        else:
            def make():
                rows = torch.cat([it.reshape(it.shape[0], -1) for it in items])
                return spatial_moments(rows[torch.isfinite(rows).all(dim=1)])

            n, s, S = _cached(("spatial", self.training_key_), make)
            # (A - mu)/sigma from the raw moments:
            #   s' = (s - n mu)/sigma,  S' = (S - s'mu - mu's + n mu'mu)/sigma^2
            mu = self.mu_.repeat(J)
            s, S = ((s - n * mu) / self.sigma_,
                    (S - torch.outer(s, mu) - torch.outer(mu, s) + n * torch.outer(mu, mu))
                    / self.sigma_ ** 2)
            where = "the training set"
        D = self.M_.shape[2]
        need = max(D * J, 10)
        if n < need:
            raise ValueError(f"{self.name}: {where} has {n} complete frames (every marker observed); "
                             f"expected at least {need} ({D} x {J} markers, or 10)")
        if items is not None and self.self_share > 0:
            n, s, S = self._with_own_frames(n, s, S)
        return n, s, S

    def _with_own_frames(self, n: int, s: Tensor, S: Tensor) -> tuple[int, Tensor, Tensor]:
        """Mix the recording's own complete frames into the training moments with the weight
        ``self_share`` (of the total); nothing changes when it has none."""
        D = self._self_data().reshape(self.M_.shape[0], -1)
        n_o, s_o, S_o = spatial_moments(D[torch.isfinite(D).all(dim=1)])
        if n_o == 0:
            return n, s, S
        N = n + n_o
        alpha, beta = (1 - self.self_share) * N / n, self.self_share * N / n_o
        return N, alpha * s + beta * s_o, alpha * S + beta * S_o

    def _basis(self, length: int) -> tuple[Tensor, Tensor]:
        """The temporal basis for windows of ``length`` frames (cached per training set)."""
        if length in self.bases_:
            return self.bases_[length]
        items = self.training_items_
        own = items is None
        items = [self._self_data()] if own else items
        runs = [(it, a, b) for it in items for a, b in complete_runs(it)]
        sources = [it[a:b].reshape(b - a, -1) for it, a, b in runs if b - a >= length]
        if not sources:
            where = "the recording itself (training=None)" if own else "the training set"
            longest = max((b - a for _, a, b in runs), default=0)
            raise ValueError(f"{self.name}: needs complete stretches (every marker observed) of at "
                             f"least {length} frames in {where} for its temporal eigenspace; the "
                             f"longest found has {longest} frames")
        stride = max(1, length // 20)
        # Column centring removes mu and the basis is scale-free, so raw training units serve.
        def make():
            return temporal_basis(sources, length, stride, self.energy, self.rank)

        V = make() if own else _cached(("temporal", self.training_key_, length, stride,
                                        self.energy, self.rank), make)
        self.bases_[length] = V
        return V

    def _temporal_fill_runs(self, Y: Tensor, runs, columns_of, observed_of, length: int,
                            scale: float | None) -> Tensor:
        """Fill each run ``(a, b, key)`` from a window around it (Eq. 13-16)."""
        T = Y.shape[0]
        out = Y.clone()
        for a, b, key in runs:
            s0, s1 = window(a, b, T, max(length, 3 * (b - a)))
            cols = columns_of(key)
            obs = observed_of(key)[s0:s1]
            if int(obs.sum()) < 2:
                continue
            V, prec = self._basis(s1 - s0)
            if not self.prior:
                prec = None
                if int(obs.sum()) < V.shape[1]:
                    V = V[:, :int(obs.sum())]
            w = edge_weights(~obs, scale)
            est = temporal_estimate(V, Y[s0:s1][:, cols], obs, w, prec)
            out[a:b, cols] = est[a - s0:b - s0]
        return out

    #: fit(X, mask, training=...): list of (T_i, J, 3) arrays with the data's markers in order
    #: (NaN allowed: only complete frames are used); None = the complete frames of the recording
    fit_data = ("training",)

    @classmethod
    def _upgrade(cls, kwargs: dict) -> dict:
        """``training`` as a hyperparameter (old): still used, with a DeprecationWarning."""
        if kwargs.get("training") is not None:
            _deprecated(cls.name, "training= as a hyperparameter", "fit(X, mask, training=...)")
        return super()._upgrade(kwargs)

    # -- contract --------------------------------------------------------------------------
    def _initialize(self) -> None:
        self.X_ = self.interp_start()
        self.bases_: dict[int, Tensor] = {}
        self.training_items_, self.training_key_ = None, None
        training = self.fit_data_.get("training", self.training)
        if training is not None:
            self.training_items_ = check_training(training, self.M_.shape[1], self.name,
                                                  dtype=self.M_.dtype, device=self.M_.device,
                                                  D=self.M_.shape[2])
            self.training_key_ = (_fingerprint(self.training_items_), str(self.M_.dtype),
                                  str(self.M_.device))

    def _estimate(self) -> Tensor:
        return self.X_

    def _finite_or_start(self, out: Tensor) -> Tensor:
        """``out`` (T x DJ) with any sample the model could not estimate (too few markers or
        frames for its statistics) taken from the interpolation start, with a warning."""
        bad = ~torch.isfinite(out) & ~self.Omega_.reshape(out.shape)
        if not bool(bad.any()):
            return out
        warnings.warn(f"{self.name}: {int(bad.sum())} missing coordinate(s) could not be "
                      f"estimated by the PCA model ({self.M_.shape[1]} markers); filled by "
                      f"linear interpolation instead", UserWarning, stacklevel=4)
        return torch.where(bad, self.interp_start().reshape(out.shape), out)


@register
class PCATrain(_PCA):
    """Gap filling from a training set through a transformed principal eigenspace (Li et al. 2020).

    Notes
    -----
    On the hyperparameters (declared in Parameters above):

    training : list of (T_i, J, D) arrays, optional
        Complete motion with the data's markers in order (see the module notes); None = the complete
        frames of the recording itself.
    variance : float
        Explained-variance rule for the rank r of ``U`` (and ``U(0)``) on the training data
        (0.9999; the paper's 0.99 loses 10-40 % accuracy on our development recordings).
    rank : int, optional
        A fixed r instead of the rule.
    centre : bool
        Body-centred coordinates (subtract each frame's centroid of observed markers).
    self_share : float
        With a training set, the recording's own complete frames (if any) join the training
        moments with this share of the weight: adapts the eigenspace to the subject (a departure
        from the paper; 0 turns it off).
    prior : bool
        ``horizontal`` only: the probabilistic-PCA prior of ``pca_blackout``.
    layout : {"vertical", "horizontal"}
        ``vertical`` (Eq. 1-4): spatial eigenspace of pieces stacked vertically, one ``T`` per frame
        template. ``horizontal`` (Eq. 5-8, our reading): temporal eigenspace of pieces concatenated
        horizontally, each marker's gap filled from its own observed frames (Eq. 16, W = I).
    window : int
        ``horizontal`` only: window length in frames around a gap (at least 3x the gap; 200 = the
        paper's test-segment length).

    Frames with every marker missing are left to ``pca_blackout`` (here: linear interpolation).

    References
    ----------
    Li, Yu, Kieu, Vuong & Zhang, IEEE Access 8 (2020), Eq. 1-8.
    """

    name = "pca_train"
    params = {
        "centre": Param(True, bool, doc="body-centred frames (True: cuts the cross-recording error, "
                                        "see experiments/results/pca.md)"),
        "layout": Param("vertical", str, choices=("vertical", "horizontal"),
                        doc="vertical = Eq. 1-4 (spatial eigenspace); horizontal = Eq. 5-8 (temporal)"),
        "window": Param(200, int, low=4, doc="horizontal layout: window around a gap (the paper's "
                                             "200-frame segments)"),
    }

    def step(self) -> dict[str, float]:
        T, J, D = self.M_.shape
        missing = ~self.Omega_.all(dim=2)
        Y = self.M_.reshape(T, -1)
        full = missing.all(dim=1)
        if self.layout == "vertical":
            out = Y
            if bool((missing.any(dim=1) & ~full).any()):
                n, s, S = self._spatial_stats()
                out = spatial_fill(Y, missing, n, s, S, variance=self.energy, rank=self.rank,
                                   centre=self.centre)
        else:
            runs = [(a, b, j) for j, a, b in ops.runs(missing)]
            runs = [r for r in runs if not bool(missing[r[0]:r[1]].all())]
            out = self._temporal_fill_runs(
                Y, runs, lambda j: slice(D * j, D * j + D), lambda j: ~missing[:, j],
                self.window, None)
        out = torch.where(full[:, None], self.X_.reshape(T, -1), out)  # blackouts: linear
        out = self._finite_or_start(out)
        self.X_ = torch.where(self.Omega_.reshape(T, -1), Y, out).reshape(self.M_.shape)
        return {"delta": 0.0}


@register
class PCABlackout(_PCA):
    """Fill whole missing frames (blackouts) from a temporal eigenspace (Li et al. 2020, Eq. 9-16).

    Frames where every marker is missing are the blackout. Other gaps (some markers missing) are
    filled first by ``pca_train`` (Eq. 4) from the same training set. Each blackout run is then
    estimated in a window of ``max(window, 3 x run)`` frames (capped at the recording) from the
    leading eigenvectors of ``A A'`` over training pieces of the window's length, by the weighted
    least squares of Eq. 16.

    Notes
    -----
    On the hyperparameters (declared in Parameters above):

    training, rank, centre
        As in ``pca_train``.
    variance : float
        Rank rule on the training data (0.99999: with the prior, more components help).
    prior : bool
        Probabilistic-PCA prior on the coefficients (Tipping & Bishop 1999): Eq. 16 becomes
        ``V^ (V~' W V~ + sigma^2 Lambda^-1)^-1 V~' W B~``. Without it (the paper's estimator) long
        blackouts blow up on real data (see experiments/results/pca.md).
    window : int
        Window length in frames around a blackout (200: the paper's segment length).
    edge_scale : float or None
        W (Eq. 13-16) = ``diag(exp(-d / (edge_scale * m)))``, d = frames to the blackout, m = its
        length: frames near the blackout weigh more. None gives W = I. Default 1.0 (compared with
        W = I in experiments/results/pca.md).

    References
    ----------
    Li, Yu, Kieu, Vuong & Zhang, IEEE Access 8 (2020), Eq. 9-16.
    """

    name = "pca_blackout"
    params = {
        "energy": Param(0.99999, float, low=0.0, high=1.0, low_open=True,
                        doc="rank rule (as pca_train); 0.99999: best of 0.99-0.99999 with the "
                            "prior on the development recordings (experiments/pca_dev.yaml)"),
        "centre": Param(True, bool, doc="body-centred frames for the partial gaps (see pca_train)"),
        "window": Param(200, int, low=4, doc="window around a blackout (the paper's 200-frame segments)"),
        "edge_scale": Param(1.0, float, low=0.0, low_open=True, allow_none=True,
                            doc="W decay length as a multiple of the blackout length; None = W = I "
                                "(1.0: best or equal of None/1/3 on the development recordings)"),
    }

    def step(self) -> dict[str, float]:
        T, J = self.M_.shape[:2]
        missing = ~self.Omega_.all(dim=2)
        Y = self.M_.reshape(T, -1)
        full = missing.all(dim=1)
        if bool((missing.any(dim=1) & ~full).any()):
            n, s, S = self._spatial_stats()
            Y = spatial_fill(Y, missing, n, s, S, variance=self.energy, rank=self.rank,
                             centre=self.centre)
        runs = [(a, b, None) for _, a, b in ops.runs(full[:, None])]
        out = self._temporal_fill_runs(Y, runs, lambda _: slice(None), lambda _: ~full,
                                       self.window, self.edge_scale)
        observed = self.Omega_.reshape(T, -1)
        out = self._finite_or_start(out)
        self.X_ = torch.where(observed, self.M_.reshape(T, -1), out).reshape(self.M_.shape)
        return {"delta": 0.0}
