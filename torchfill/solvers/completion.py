"""Low-rank tensor completion baselines of the CP paper's Tables 4-6: ``halrtc`` and ``pstnn``.

Both complete the recording as the tensor ``X`` (frames x markers x xyz, the CP family's layout)
under the constraint ``P_Omega(X) = P_Omega(M)`` by ADMM, with the penalty ``rho`` (``beta``)
growing by ``mu`` per iteration (inexact ALM, as in :mod:`torchfill.solvers.matrix`):

* ``halrtc`` -- Liu, Musialski, Wonka & Ye (2013), HaLRTC: ``min sum_i alpha_i ||X_(i)||_*``
  over the three unfoldings, split as ``M_i = X`` (their Algorithm "HaLRTC", Eq. 23 for the model,
  updates of ``M_i``, ``X`` and ``Y_i`` in their ADMM).
* ``pstnn`` -- Jiang, Huang, Zhao & Deng (2020): ``min ||L||_{PSTNN}`` (partial sum of the tubal
  nuclear norm: per Fourier frontal slice, the singular values beyond the first ``N``), split as
  ``L = X``. The t-SVD's FFT runs along the **xyz mode** (mode 3): the frontal slices are then
  the frames x markers matrices, whose low rank is the correlation of markers over time -- the
  structure a fill needs; the paper's tensor ``m x p x 3`` is the same layout. FFT along time
  would leave 41 x 3 slices (rank <= 3: nothing to complete with) and FFT along markers mixes
  markers in an arbitrary order.

Honest choices (observed data only): both start from the linearly interpolated gaps; ``rho_0``
is set relative to the data (first threshold = the largest singular value of the start, as in
Lin et al.'s inexact ALM); they stop when the fill (the missing entries) changes by less than
``tol`` relative. Data are centred per axis and scaled to unit variance by the base class.

References
----------
J. Liu, P. Musialski, P. Wonka and J. Ye, "Tensor completion for estimating missing values in
visual data", IEEE TPAMI 35(1), 208-220, 2013.
T.-X. Jiang, T.-Z. Huang, X.-L. Zhao and L.-J. Deng, "Multi-dimensional imaging data recovery via
minimizing the partial sum of tubal nuclear norm", J. Comput. Appl. Math. 372, 112680, 2020.
S. Mohaoui and A. Dmytryshyn, Pattern Anal. Appl. 27, 2024 (Tables 4-6: the comparison).
"""
from __future__ import annotations

import torch

from .. import ops
from .base import Param, Solver, register
from ..ops import gram_svd
from .matrix import _rel_change, svt

Tensor = torch.Tensor


# --------------------------------------------------------------------------------------------
# Building blocks
# --------------------------------------------------------------------------------------------
def halrtc_m_step(X: Tensor, Y: Tensor, alpha: float, rho: float, mode: int) -> tuple[Tensor, int]:
    """``M_i = fold_i[D_{alpha_i / rho}(X_(i) + Y_i(i) / rho)]`` (HaLRTC, the M_i-update)."""
    Z, r = svt(ops.unfold(X + Y / rho, mode), alpha / rho)
    return ops.fold(Z, mode, X.shape), r


def halrtc_x_step(M: list[Tensor], Y: list[Tensor], rho: float, T: Tensor,
                  Omega: Tensor) -> Tensor:
    """``X_Omega^c = (1/N sum_i (M_i - Y_i / rho))_Omega^c``, ``X_Omega = T_Omega`` (HaLRTC)."""
    avg = sum(Mi - Yi / rho for Mi, Yi in zip(M, Y)) / len(M)
    return torch.where(Omega, T, avg)


def pstnn_shrink(Z: Tensor, tau: float, N: int) -> tuple[Tensor, int]:
    """Prox of ``tau ||.||_{PSTNN}``: partial singular value thresholding of every frontal slice
    of ``Z`` (I1 x I2 x I3) in the Fourier domain along mode 3 (Jiang et al. 2020, the PSTNN
    shrinkage operator). The FFT is orthonormal, so ``tau`` is in the data's units; the real FFT
    visits the independent half of the slices (the others are their conjugates). Returns the
    result and the largest slice rank kept."""
    Zf = torch.fft.rfft(Z, dim=2, norm="ortho")
    slices, rank = [], 0
    for k in range(Zf.shape[2]):
        S, r = ops.svt(Zf[:, :, k], tau, keep=N)
        slices.append(S)
        rank = max(rank, r)
    return torch.fft.irfft(torch.stack(slices, dim=2), n=Z.shape[2], dim=2, norm="ortho"), rank


def constrain(L: Tensor, M: Tensor, Omega: Tensor) -> Tensor:
    """``X = P_Omega(M) + P_Omega^c(L)``: the observed entries are the data."""
    return torch.where(Omega, M, L)


# --------------------------------------------------------------------------------------------
# Solvers
# --------------------------------------------------------------------------------------------
class _ADMMCompletion(Solver):
    """Shared state: the tensor, the growing penalty, the stopping rule on the fill."""

    params = {
        "max_iter": Param(500, int, low=1, doc="cap on ADMM iterations"),
        "tol": Param(1e-4, float, low=0.0,
                     doc="stop when the fill (missing entries) changes by less than this, "
                         "relative, and the splitting residual is below it too"),
        "rho": Param(1.0, float, low=0.0, low_open=True,
                     doc="initial penalty relative to the data: rho_0 = rho / sigma_1 of the "
                         "start's temporal unfolding (first threshold = sigma_1)"),
        "mu": Param(1.1, float, low=1.0,
                    doc="penalty growth per iteration (inexact ALM); 1.0 = fixed penalty"),
        "rho_max": Param(1e6, float, low=0.0, low_open=True, doc="cap on rho relative to rho_0"),
    }

    def _initialize(self) -> None:
        if self.M_.ndim != 3:
            raise ValueError(f"{self.name}: expected a third-order tensor (frames x markers x "
                             f"xyz), found shape {tuple(self.M_.shape)}")
        self.X_ = self.interp_start()
        self.Gap_ = ~self.Omega_
        T = self.X_.shape[0]
        s1 = float(gram_svd(self.X_.reshape(T, -1) if T >= self.X_[0].numel()
                            else self.X_.reshape(T, -1).T)[0][0]) if self.X_.numel() else 1.0
        self.rho0_ = self.rho / max(s1, 1e-12)
        self.rho_ = self.rho0_
        self._setup()

    def _grow_rho(self) -> None:
        self.rho_ = min(self.rho_ * self.mu, self.rho0_ * self.rho_max)

    def should_stop(self, info: dict[str, float]) -> bool:
        return info["delta"] < self.tol and info["primal"] < self.tol

    def _estimate(self) -> Tensor:
        return self.X_

    def _setup(self) -> None:
        raise NotImplementedError


def _primal(A: Tensor, B: Tensor) -> float:
    return float((A - B).norm() / B.norm().clamp_min(1e-300))


@register
class HaLRTC(_ADMMCompletion):
    """HaLRTC (Liu et al. 2013): ``min sum_i alpha_i ||X_(i)||_* s.t. X_Omega = T_Omega`` by ADMM.

    One ``step()`` is one ADMM iteration over the three unfoldings (frames, markers, xyz)::

        M_i = fold_i[D_{alpha_i/rho}(X_(i) + Y_i(i)/rho)]      # for i = 1..3
        X   = P_Omega(T) + P_Omega^c(1/N sum_i (M_i - Y_i/rho))
        Y_i = Y_i - rho (M_i - X)

    ``alpha`` defaults to the paper's equal weights. On shared-window gaps of many markers the
    nuclear norms pull the fill toward the mean pose (CMU 02_01, 30 x 100: 137 mm; other weights
    did not help; see experiments/results/cp_baselines.md).

    References
    ----------
    J. Liu, P. Musialski, P. Wonka and J. Ye, IEEE TPAMI 35(1), 2013 (HaLRTC).
    """

    name = "halrtc"
    params = {
        "alpha": Param((1 / 3, 1 / 3, 1 / 3), (tuple, list),
                       doc="alpha_i, weights of the nuclear norms of the frames/markers/xyz "
                           "unfoldings (the paper's equal weights)"),
    }

    def _setup(self) -> None:
        if len(self.alpha) != 3 or any(not isinstance(a, (int, float)) or a < 0
                                       for a in self.alpha):
            raise ValueError(f"{self.name}: alpha expected 3 non-negative numbers, "
                             f"found {self.alpha!r}")
        self.Y_ = [torch.zeros_like(self.X_) for _ in range(3)]
        self.Mi_ = [self.X_.clone() for _ in range(3)]

    @torch.no_grad()
    def step(self) -> dict[str, float]:
        rho, ranks = self.rho_, []
        for i in range(3):                                   # M_i-update (SVT of unfolding i)
            self.Mi_[i], r = halrtc_m_step(self.X_, self.Y_[i], float(self.alpha[i]), rho, i)
            ranks.append(r)
        X_old = self.X_
        self.X_ = halrtc_x_step(self.Mi_, self.Y_, rho, self.M_, self.Omega_)   # X-update
        for i in range(3):                                   # Y_i-update (multipliers)
            self.Y_[i] = self.Y_[i] - rho * (self.Mi_[i] - self.X_)
        self._grow_rho()
        delta = _rel_change(self.X_, X_old, self.Gap_)
        primal = max(_primal(Mi, self.X_) for Mi in self.Mi_)
        return {"delta": delta, "primal": primal, "rho": rho,
                "rank1": ranks[0], "rank2": ranks[1], "rank3": ranks[2]}


@register
class PSTNN(_ADMMCompletion):
    """PSTNN completion (Jiang et al. 2020): ``min ||L||_{PSTNN} s.t. P_Omega(L) = P_Omega(M)``.

    ``||L||_{PSTNN}`` sums, over the Fourier frontal slices (FFT along xyz, see the module
    docstring), the singular values beyond the first ``N``. ADMM on the splitting ``L = X``
    (``beta`` = rho), one ``step()``::

        L      = PSTNN shrinkage_{N, 1/beta}(X - Lambda/beta)
        X      = P_Omega(M) + P_Omega^c(L + Lambda/beta)
        Lambda = Lambda + beta (L - X)

    References
    ----------
    T.-X. Jiang, T.-Z. Huang, X.-L. Zhao and L.-J. Deng, J. Comput. Appl. Math. 372, 2020.
    """

    name = "pstnn"
    params = {
        "N": Param(3, int, low=0,
                   doc="number of leading singular values of each Fourier slice left "
                       "unpenalized (the partial sum's N; 0 = the tubal nuclear norm). "
                       "Chosen on CMU 02_01 (seed 0, 10x20 / 20x50 / 30x100): N = 0 / 3 / 8 gave "
                       "0.56 / 0.36 / 0.31, 14.9 / 1.96 / 6.3, 136 / 7.1 / 44.5 mm RMSE"),
    }

    def _setup(self) -> None:
        self.Lambda_ = torch.zeros_like(self.X_)
        self.L_ = self.X_.clone()

    @torch.no_grad()
    def step(self) -> dict[str, float]:
        beta = self.rho_
        self.L_, rank = pstnn_shrink(self.X_ - self.Lambda_ / beta, 1.0 / beta, self.N)  # L
        X_old = self.X_
        self.X_ = constrain(self.L_ + self.Lambda_ / beta, self.M_, self.Omega_)      # X
        self.Lambda_ = self.Lambda_ + beta * (self.L_ - self.X_)                      # Lambda
        self._grow_rho()
        delta = _rel_change(self.X_, X_old, self.Gap_)
        return {"delta": delta, "primal": _primal(self.L_, self.X_), "rho": beta,
                "rank": rank}
