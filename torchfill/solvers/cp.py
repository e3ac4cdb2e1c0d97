"""CP, SmoothCP and SparseCP completion by HALS (Mohaoui & Dmytryshyn 2024).

The recording is the tensor ``X`` (frames x markers x xyz) modelled as a sum of ``R`` rank-one
terms ``sum_r lam_r a_r(1) o a_r(2) o a_r(3)`` with unit-norm factor vectors (:class:`CPTensor`).
Algorithm 1 of the paper alternates

* a decomposition step: hierarchical ALS (HALS), one rank-one component at a time, on the residue
  ``X_r = X - sum_{k != r} lam_k a_k(1) o a_k(2) o a_k(3)``: plain CP (Eq. 22, 25), SmoothCP
  (projected gradient with a first-difference penalty, Eqs. 32-33) or SparseCP (projected
  (sub)gradient with an l1 penalty, Eqs. 34-35);
* a completion step (Eq. 26): ``X = P_Omega^c(model) + P_Omega(M)``;
* a rank increase (Eq. 36) whenever the observed residual ``nu = ||E_Omega||_F^2`` stalls.

What differs from the authors' MATLAB demo (each measured on CMU 02_01, see
``experiments/results/cp.md``):

* the true frames x markers x xyz tensor (the demo's column-major reshape scrambles markers and
  coordinates), started from the linear-interpolation fill instead of the observed mean;
* every component is updated in every sweep (the demo updates the 10 smallest), visited mode by
  mode as in Cichocki & Phan's HALS, and the residue is never formed: ``X_r x_{-n} {a_r}`` comes
  from one MTTKRP per mode and the Gram matrices of the factors (two passes over ``X`` per sweep);
* a new component (Eq. 36) starts from the leading singular vectors of the current observed
  residual instead of random vectors, so it begins where the fit is worst;
* the rank is chosen honestly on observed data: a copy of the gap pattern, shifted in time, is held
  out of the observed entries; the rank grows while the held-out error improves (by at least
  ``min_gain``, ``rank_patience`` tries); the best rank is restored and refitted with every observed
  entry until ``nu`` stalls again (``holdout=None`` gives the paper's rule: grow until
  ``max_rank``, stop when ``||X - X_old|| / ||X_old|| < tol``). Iterating the refit on to
  ``tol = 1e-6`` slowly overfits: on CMU 02_01 (30 markers x 100 frames) the error rose from 6.0
  to 6.9 mm between sweeps 250 and 1000;
* the SmoothCP penalty is relative to ``lam_r^2`` (scale-free ``alpha``), on the time mode only by
  default, and its projected gradient is preconditioned by the Hessian ``I + 2 alpha D^T D``
  (applied by FFT), which makes ``gamma = 1`` exact in one step (``precondition=False``: plain
  steps ``gamma / (1 + 8 alpha)``); inner loops are warm-started and stop once converged;
* SparseCP soft-thresholds the scaled column ``lam_r a_r(n)`` (the proximal step of the l1 term,
  which gives exact zeros; the subgradient steps of Eq. 35 never settle), with the threshold a
  fraction ``alpha`` of the column's RMS entry; ``subgradient=True`` gives Eq. 35 literally.

References
----------
S. Mohaoui and A. Dmytryshyn, "CP decomposition-based algorithms for completion problem of motion
capture data", Pattern Analysis and Applications 27, 2024. doi:10.1007/s10044-024-01342-4
A. Cichocki and A.-H. Phan, "Fast local algorithms for large scale nonnegative matrix and tensor
factorizations", IEICE Trans. Fundamentals E92-A(3), 2009 (HALS).
"""
from __future__ import annotations

import math

import torch

from .. import ops
from .base import Param, Solver, register
from .factorized import CPTensor
from .base import _deprecated
from .holdout import holdout_for, holdout_params

Tensor = torch.Tensor
_TINY = 1e-300


# --------------------------------------------------------------------------------------------
# Building blocks (plain functions on tensors, one per equation)
# --------------------------------------------------------------------------------------------
def smoothing_filter(u: Tensor, alpha: float) -> Tensor:
    """``(I + 2 alpha D^T D)^{-1} u`` in O(I log I), ``u`` a vector or the columns of a matrix.

    ``D^T D`` (first differences, free ends) is the circulant second difference of the
    half-sample-symmetric extension of ``u`` to ``2I`` points, so the FFT diagonalizes it with
    eigenvalues ``2 - 2 cos(pi k / I)``.
    """
    I = u.shape[0]
    w = torch.fft.rfft(torch.cat([u, u.flip(0)]), dim=0)
    k = torch.arange(w.shape[0], dtype=u.dtype, device=u.device)
    gain = 1.0 / (1.0 + 2.0 * alpha * (2.0 - 2.0 * torch.cos(math.pi * k / I)))
    if u.ndim > 1:
        gain = gain.reshape(-1, *([1] * (u.ndim - 1)))
    return torch.fft.irfft(w * gain, n=2 * I, dim=0)[:I]


def smooth_column(a: Tensor, u: Tensor, alpha: float, gamma: float, k_max: int,
                  tol: float, precondition: bool = True) -> tuple[Tensor, int]:
    """SmoothCP update of one factor column: projected gradient (Eqs. 32-33).

    Minimizes ``f(a) = -<u, a> + 1/2 ||a||^2 + alpha ||D a||^2`` over unit vectors, where
    ``u = g / lam_r``: Eq. 32 divided by ``lam_r^2`` (the penalty is relative to the component's
    energy, so ``alpha`` is scale-free). Each step is ``a <- P_C(a - gamma H^{-1} grad f(a))``
    with ``P_C`` the projection on the unit sphere (Eq. 33) and

    * ``precondition=True`` (default): ``H = I + 2 alpha D^T D``, the Hessian of ``f``, applied by
      FFT (:func:`smoothing_filter`); the step is then ``a - gamma (a - H^{-1} u)``, and
      ``gamma = 1`` lands on the normalized minimizer of ``f`` in one step (the way Eq. 22 is the
      normalized least-squares solution for plain CP);
    * ``precondition=False``: the plain gradient of Eq. 32 with step ``gamma / (1 + 8 alpha)``
      (``1 + 8 alpha`` bounds the Lipschitz constant since ``||D^T D|| <= 4``).

    Warm-started from the current column ``a``; stops after ``k_max`` steps or when the column
    moves less than ``tol``. Returns the column and the number of steps.
    """
    h = smoothing_filter(u, alpha) if precondition else None
    step = gamma if precondition else gamma / (1.0 + 8.0 * alpha)
    for k in range(1, k_max + 1):
        if precondition:
            a_new = a - step * (a - h)                              # H^{-1} grad f = a - H^{-1} u
        else:
            a_new = a - step * (a - u + 2.0 * alpha * ops.difference_gram(a))   # Eq. 32
        a_new = a_new / a_new.norm().clamp_min(_TINY)              # Eq. 33: P_C, unit sphere
        if precondition and gamma == 1.0:
            return a_new, k                                         # exact in one step
        moved = float((a_new - a).norm())
        a = a_new
        if moved < tol:
            break
    return a, k


def sparse_column(a: Tensor, g: Tensor, lam_r: Tensor, beta: float, gamma: float, k_max: int,
                  tol: float, subgradient: bool = False) -> tuple[Tensor, int]:
    """SparseCP update of one scaled factor column ``lam_r a_r(n)`` (Eqs. 34-35).

    Default: the proximal (soft-thresholding) step of
    ``1/2 ||X_r_(n) - s z^T||^2 + beta ||s||_1`` in the scaled column ``s = lam_r a_r(n)``
    (``||z|| = 1``), i.e. ``s = S_beta(g)`` with ``g = X_r x_{-n} {a_r}``: an exact block
    minimization, so every sweep decreases the penalized objective; ``lam_r = ||s||`` and
    ``a_r(n) = s / lam_r`` (a column thresholded to zero keeps its direction with ``lam_r = 0``).
    ``subgradient=True``: Eq. 35 literally, ``a <- P_C(a - gamma (a - g / lam_r + beta / lam_r
    Sgn(a)))`` for ``k_max`` steps (or until the column moves less than ``tol``), warm-started
    from the current unit column ``a``. Returns the scaled column and the number of steps.
    """
    if not subgradient:
        return ops.soft_threshold(g, beta), 1
    lam = lam_r.clamp_min(_TINY)
    u = g / lam
    for k in range(1, k_max + 1):
        a_new = a - gamma * (a - u + (beta / lam) * torch.sign(a))        # Eq. 35
        a_new = a_new / a_new.norm().clamp_min(_TINY)                     # P_C, unit sphere
        moved = float((a_new - a).norm())
        a = a_new
        if moved < tol:
            break
    return _signed(g, a), k


def _signed(g: Tensor, a: Tensor) -> Tensor:
    """``lam_r a_r`` with ``lam_r = <X_r, a_r(1) o a_r(2) o a_r(3)> = <g, a>`` (Eq. 25); a negative
    weight is absorbed into the column (the norm of the result is ``|lam_r|``)."""
    return (g @ a) * a


def complete(M: Tensor, Omega: Tensor, Y: Tensor) -> Tensor:
    """Completion step (Eq. 26): ``X = P_Omega^c(Y) + P_Omega(M)``."""
    return torch.where(Omega, M, Y)


def leading_rank_one(E: Tensor) -> tuple[Tensor, list[Tensor]]:
    """Rank-one start for a new component (our choice for Eq. 36): the leading singular vectors of
    the residual ``E`` (T x J x 3).

    ``a(1)`` and the right vector ``v`` (3J) are the leading singular pair of the temporal
    unfolding, computed from its 3J x 3J Gram matrix; ``v`` reshaped to J x 3 gives ``a(2)``,
    ``a(3)`` as its leading singular pair. ``lam = <E, a(1) o a(2) o a(3)>`` >= 0.
    """
    T, J, K = E.shape
    E1 = E.reshape(T, J * K)
    _, V = torch.linalg.eigh(E1.T @ E1)
    v = V[:, -1]
    a1 = E1 @ v
    a1 = a1 / a1.norm().clamp_min(_TINY)
    U2, _, V3 = torch.linalg.svd(v.reshape(J, K), full_matrices=False)
    a2, a3 = U2[:, 0], V3[0]
    lam = a2 @ (a1 @ E1).reshape(J, K) @ a3
    if lam < 0:
        lam, a1 = -lam, -a1
    return lam, [a1, a2, a3]


# --------------------------------------------------------------------------------------------
# The solvers
# --------------------------------------------------------------------------------------------
class _HALSCP(Solver):
    """Shared loop of Algorithm 1 (CP, SmoothCP, SparseCP); subclasses set ``_update_column``."""

    params = {
        "rank": Param(1, int, low=1, doc="initial rank R (Algorithm 1 starts at 1)"),
        "max_rank": Param(80, int, low=1,
                          doc="R_max, cap on the rank; the hold-out chose 10-65 on the CMU/HDM05 "
                              "recordings (smooth_cp reached 80 in 3 of 54 table runs)"),
        "eps": Param(1e-2, float, low=0.0,
                     doc="epsilon of Eq. 36: add a component when |nu - nu_old| / nu <= eps "
                         "(nu = observed squared residual); the authors use 1e-3, which took 3x "
                         "the sweeps for the same accuracy on CMU 02_01"),
        **holdout_params("shifted_gaps", 0.2, ", the paper's rule: grow to max_rank (with a "
                                              "hold-out the rank grows while its error improves)"),
        "rank_patience": Param(5, int, low=0,
                               doc="rank increases without held-out improvement before the rank "
                                   "search stops (chosen on CMU 02_01/85_02); counted in rank "
                                   "increases, so not called patience, which is in iterations"),
        "min_gain": Param(0.005, float, low=0.0, high=1.0,
                          doc="a rank counts as better only if it lowers the held-out RMSE by "
                              "this fraction (0.5 %: smaller gains were noise on CMU 02_01)"),
        "max_iter": Param(2000, int, low=1, doc="cap on sweeps (decomposition + completion)"),
        "tol": Param(1e-6, float, low=0.0,
                     doc="stop when ||X - X_old|| / ||X_old|| < tol (the paper's 1e-6)"),
    }

    renamed = {"rank_max": "max_rank", "patience": "rank_patience"}
    renamed_attributes = {"cp_": "decomposition_", "rank_chosen_": "chosen_rank_"}

    @classmethod
    def _upgrade(cls, kwargs: dict) -> dict:
        """``holdout=True/False`` (old) is ``holdout="shifted_gaps"`` / ``None``."""
        if isinstance(kwargs.get("holdout"), bool):
            new = "shifted_gaps" if kwargs["holdout"] else None
            _deprecated(cls.name, f"holdout={kwargs['holdout']}", f"holdout={new!r}")
            kwargs["holdout"] = new
        return super()._upgrade(kwargs)

    # -- state -------------------------------------------------------------------------------
    def _initialize(self) -> None:
        M = self.M_
        if M.ndim != 3:
            raise ValueError(f"{self.name}: expected a third-order tensor "
                             f"(frames x markers x xyz), "
                             f"found shape {tuple(M.shape)}")
        # better only by a clear margin: min_gain relative, 1e-9 absolute (unit-variance data)
        self.holdout_ = holdout_for(self, min_gain=self.min_gain, atol=1e-9)
        self.X_ = complete(M, self.W_, self.interp_start(self.W_))       # linear-interp start
        self.searching_ = self.holdout_.active
        self.chosen_ = False                     # True once the hold-out has chosen the rank
        self.val_history_: list[tuple[int, float]] = []
        self.nu_ = math.inf
        self.inner_steps_ = 0
        E = self.X_
        T, J, K = M.shape
        self.decomposition_ = CPTensor(M.new_zeros(0),
                            [M.new_zeros(T, 0), M.new_zeros(J, 0), M.new_zeros(K, 0)])
        for _ in range(min(self.rank, self.max_rank)):
            self._add_component(E)
            E = self.X_ - self.model()

    @property
    def W_(self) -> Tensor:
        """The training entries: observed and not held out (all observed once the rank is chosen)."""
        return self.holdout_.fit_mask

    @property
    def rank_(self) -> int:
        return int(self.decomposition_.weights.shape[0])

    def _add_component(self, E: Tensor) -> None:
        """Rank increase (Eq. 36), the new component from the residual's leading vectors."""
        lam, a = leading_rank_one(E)
        self.decomposition_.weights = torch.cat([self.decomposition_.weights, lam.reshape(1)])
        self.decomposition_.factors = [torch.cat([A, v[:, None]], dim=1) for A, v in zip(self.decomposition_.factors, a)]

    # -- one sweep ---------------------------------------------------------------------------
    def _update_column(self, g: Tensor, a: Tensor, lam_r: Tensor, n: int) -> Tensor:
        """New ``lam_r a_r(n)`` from the residue contraction ``g = X_r x_{-n} {a_r}``, the current
        unit column ``a`` and weight ``lam_r``."""
        raise NotImplementedError

    def decomposition_step(self, X: Tensor) -> None:
        """One HALS pass: every column ``a_r(n)`` (Eq. 22 / 32-33 / 34-35) and ``lam_r`` (Eq. 25),
        one block at a time with the others fixed.

        The blocks are visited mode by mode (``for n: for r``, the order of Cichocki & Phan's
        HALS); within mode ``n`` the other factors are fixed, so ``X x_{-n} {a_r}`` is one MTTKRP
        for every ``r`` and the residue contraction of component ``r`` (Eq. 22) is
        ``P[:, r] - sum_{k != r} lam_k a_k(n) Q[k, r]`` with ``Q`` the Hadamard product of the other
        factors' Gram matrices (unit diagonal). The columns are held scaled, ``lam_r a_r(n)``.
        """
        lam = self.decomposition_.weights
        A = [F.clone() for F in self.decomposition_.factors]
        Z = None
        for n in range(3):
            others = [m for m in range(3) if m != n]
            P = ops.mttkrp(X, A, n, Z).T.contiguous()                   # R x I_n
            Q = (A[others[0]].T @ A[others[0]]) * (A[others[1]].T @ A[others[1]])
            S = (A[n] * lam).T.contiguous()                         # rows: lam_r a_r(n)
            St = S.T
            rows, P_rows, Q_rows, A_rows = S.unbind(0), P.unbind(0), Q.unbind(0), A[n].T.unbind(0)
            for r in range(lam.shape[0]):
                # Eq. 22: X_r x_{-n} {a_r} = P[:, r] - sum_{k != r} lam_k a_k(n) Q[k, r]
                g = torch.addmv(P_rows[r] + rows[r], St, Q_rows[r], alpha=-1.0)
                rows[r].copy_(self._update_column(g, A_rows[r], lam[r], n))
            lam = S.norm(dim=1)                                      # Eq. 25 (lam_r = ||g||, CP)
            # a column thresholded to zero (SparseCP) keeps its old direction, with lam_r = 0
            A[n] = torch.where(lam[:, None] > 0, S / lam.clamp_min(_TINY)[:, None], A[n].T).T
            if n == 0:
                Z = (X.reshape(X.shape[0], -1).T @ A[0]).reshape(X.shape[1], X.shape[2], -1)
        self.decomposition_.weights = lam
        self.decomposition_.factors = [F.contiguous() for F in A]

    def model(self) -> Tensor:
        """The full CP tensor ``sum_r lam_r a_r(1) o a_r(2) o a_r(3)``."""
        A = self.decomposition_.factors
        return ((A[0] * self.decomposition_.weights) @ ops.khatri_rao(A[1], A[2]).T).reshape(self.M_.shape)

    def step(self) -> dict[str, float]:
        with torch.no_grad():
            self.decomposition_step(self.X_)
            Y = self.model()
            X_new = complete(self.M_, self.W_, Y)                 # Eq. 26
            delta = float((X_new - self.X_).norm() / self.X_.norm().clamp_min(_TINY))
            self.X_ = X_new
            E = torch.where(self.W_, self.M_ - Y, torch.zeros((), dtype=Y.dtype, device=Y.device))
            nu = float((E ** 2).sum())
            # Eq. 36 trigger; an exact fit (nu at rounding level) counts as stalled too
            exact = nu <= 1e-24 * float(self.W_.sum())
            stalled = abs(self.nu_ - nu) <= self.eps * max(nu, _TINY) or exact
            self.nu_ = nu
            info = {"delta": delta, "nu": nu, "rank": float(self.rank_)}
            if stalled:
                self._on_stall(Y, E, info)
            return info

    def _on_stall(self, Y: Tensor, E: Tensor, info: dict) -> None:
        """The fit at this rank has stalled: score it on the hold-out, then grow (Eq. 36)."""
        if self.searching_:
            err = self.holdout_.rmse(Y, self.M_)
            info["holdout_rmse"] = err
            self.val_history_.append((self.rank_, err))
            self.holdout_.offer(err, self._snapshot, self.n_iter_ + 1)
            if self.holdout_.n_bad > self.rank_patience or self.rank_ >= self.max_rank:
                self._finish_search()
                return
        if self.chosen_:
            info["final_stall"] = 1.0
            return
        if self.rank_ < self.max_rank:
            self._add_component(E)
            self.nu_ = math.inf

    def _snapshot(self) -> dict[str, Tensor]:
        return {k: v.clone() for k, v in self.decomposition_.state_dict().items()}

    def _finish_search(self) -> None:
        """Restore the rank with the best held-out error; refit with every observed entry."""
        state = self.holdout_.release()
        self.decomposition_.weights = state["weight_vector"]
        self.decomposition_.factors = [state[f"factor_{n}"] for n in range(3)]
        self.searching_ = False
        self.chosen_ = True
        self.chosen_rank_ = self.rank_
        self.chosen_iter_ = self.holdout_.best_iter
        self.X_ = complete(self.M_, self.W_, self.model())
        self.nu_ = math.inf

    def should_stop(self, info: dict[str, float]) -> bool:
        """Once the rank is settled: stop on ``||X - X_old|| / ||X_old|| < tol`` (the paper's
        rule) or, after a hold-out rank choice, at the first stall of ``nu`` (Eq. 36's trigger),
        the same point at which every rank was scored on the hold-out."""
        if self.searching_:
            return False
        return info.get("delta", math.inf) < self.tol or bool(info.get("final_stall", 0.0))

    def _estimate(self) -> Tensor:
        return self.X_


@register
class CP(_HALSCP):
    """CP completion by HALS (Mohaoui & Dmytryshyn 2024, Algorithm 1 with Eqs. 22, 25, 26, 36).

    Defaults chosen on CMU 02_01 and 85_02 with simulated gaps and checked on every CMU and
    HDM05 recording in ``shared/data``.

    References
    ----------
    S. Mohaoui and A. Dmytryshyn, "CP decomposition-based algorithms for completion problem of
    motion capture data", Pattern Anal. Appl. 27, 2024.
    """

    name = "cp"

    def _update_column(self, g, a, lam_r, n):
        return g                                    # Eq. 22: lam_r a_r(n) = X_r x_{-n} {a_r}


class _RegularizedCP(_HALSCP):
    params = {
        "gamma": Param(1.0, float, low=0.0, low_open=True, high=2.0,
                       doc="gamma, the inner step, in units of 1/Lipschitz (1 = the classic step)"),
        "k_max": Param(50, int, low=1, doc="K_max, cap on inner projected-gradient steps"),
        "inner_tol": Param(1e-6, float, low=0.0,
                           doc="inner loop stops when the column moves less than this"),
        "alpha_modes": Param((0,), (tuple, list),
                             doc="modes (0 = time, 1 = markers, 2 = xyz) that carry the prior "
                                 "alpha; the others are updated as plain CP (Eq. 22)"),
    }

    def _alpha(self, n: int) -> float:
        return self.alpha if n in self.alpha_modes else 0.0


@register
class SmoothCP(_RegularizedCP):
    """SmoothCP: CP completion with a first-difference smoothness prior on the factors
    (Mohaoui & Dmytryshyn 2024, Eqs. 32-33).

    ``alpha`` (alpha_n of the paper) is relative to ``lam_r^2``: the column update low-passes
    ``g / lam_r`` with the filter ``(I + 2 alpha D^T D)^{-1}``. Default on the time mode only
    (smoothness across the arbitrary marker order or the xyz axes has no meaning).
    """

    name = "smooth_cp"
    params = {
        "alpha": Param(0.5, float, low=0.0,
                       doc="alpha_n, smoothness weight relative to lam_r^2 (chosen on CMU "
                           "02_01 / 85_02 at 120 Hz)"),
        "precondition": Param(True, bool,
                              doc="precondition the gradient of Eq. 32 by its Hessian (FFT); "
                                  "False gives the plain projected gradient"),
    }

    def _update_column(self, g, a, lam_r, n):
        alpha = self._alpha(n)
        if alpha == 0.0:
            return g
        a, k = smooth_column(a, g / lam_r.clamp_min(_TINY), alpha, self.gamma, self.k_max,
                             self.inner_tol, self.precondition)
        self.inner_steps_ += k
        return _signed(g, a)


@register
class SparseCP(_RegularizedCP):
    """SparseCP: CP completion with an l1 sparsity prior on the factors
    (Mohaoui & Dmytryshyn 2024, Eqs. 34-35).

    Each scaled column ``lam_r a_r(n)`` of a mode in ``alpha_modes`` is soft-thresholded at
    ``alpha`` times its RMS entry (scale-free). Default on the marker mode (a component then
    involves fewer markers); the default ``alpha`` is small because stronger thresholds degraded
    the fills on CMU 02_01 (see ``experiments/results/cp.md``).
    """

    name = "sparse_cp"
    params = {
        "alpha": Param(0.003, float, low=0.0,
                       doc="alpha_n: the l1 threshold as a fraction of the column's RMS entry; "
                           "0.01 and above degraded CMU 02_01 fills "
                           "(see experiments/results/cp.md)"),
        "alpha_modes": Param((1,), (tuple, list),
                             doc="modes that carry the l1 prior (default: markers)"),
        "subgradient": Param(False, bool,
                             doc="literal Eq. 35 (subgradient) instead of the proximal step"),
    }

    def _update_column(self, g, a, lam_r, n):
        alpha = self._alpha(n)
        if alpha == 0.0:
            return g
        # beta = alpha times the RMS entry of g, so the threshold is relative to the component
        beta = alpha * g.norm() / math.sqrt(a.shape[0])
        s, k = sparse_column(a, g, lam_r, beta, self.gamma, self.k_max, self.inner_tol,
                             self.subgradient)
        self.inner_steps_ += k
        return s
