"""Tucker and TuckerTNN gap filling (Mohaoui & Dmytryshyn 2026, Sections 4-5, Algorithm 2).

The recording is the third-order tensor ``X`` (frames x markers x xyz) with observed set ``Omega``
and data ``T``. The Tucker model ``G x_1 A(1) x_2 A(2) x_3 A(3)`` (column-orthonormal factors) is
fitted by proximal block coordinate descent; one iteration updates the factors (Eq. 17), the core
(Eq. 18) and the recovered tensor (Eq. 19 for ``tucker``; Eqs. 24-30 for ``tucker_tnn``, which adds
a nuclear norm on the temporal unfolding ``X_(1)``), then grows the ranks when the observed residual
stalls (Eqs. 31-32).

What differs from the authors' code, and why (all of it uses observed data only):

* Start: the gaps are linearly interpolated, then a truncated HOSVD gives ``A(n)`` and ``G``
  (the authors start from random factors, which leaves some markers hundreds of mm off).
* The authors keep the iterate with the best error against the ground truth; we may not. The
  error on the missing entries first falls then rises as the ranks grow, so the rank/iterate is
  chosen on a **validation set of observed data**: the recording's own gap pattern, moved in
  time onto observed samples (same markers, lengths and simultaneity; at most 5 % of the
  observed samples; ``holdout="segments"`` uses single-marker observed runs instead), is hidden
  from the fit while the rank schedule runs, once for each ``eps`` (1e-2, then 1e-4, from the
  same start; the 1e-4 schedule ends after a trial when it is still far behind, see
  ``EPS_TRIAL_RATIO``); the iterate with the smallest error on it is restored, the data are given back,
  and the fit continues at that rank until it converges (``holdout="shifted_gaps"``, the default).
  ``holdout=None`` runs the paper's schedule and returns the last iterate.
* The nuclear-norm sub-problem (Eq. 24) has a closed form, ``D_{lam/(1+rho_x)}((Z + rho_x X_k) /
  (1+rho_x))``; it is the default. The paper's accelerated proximal gradient (Algorithm 1) is
  available as ``x_step="apg"`` and converges to the same point (tested).

References
----------
S. Mohaoui and A. Dmytryshyn, "Tucker tensor completion for motion capture data with missing
markers", 2026 (Eqs. 17-19, 24-32; Algorithms 1-2).
K.-C. Toh and S. Yun, "An accelerated proximal gradient algorithm for nuclear norm regularized
linear least squares problems", Pacific J. Optim. 6 (2010) 615-640.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from .. import ops
from .base import Param, Solver, _deprecated, register
from .factorized import TuckerTensor
from .holdout import HoldOut, holdout_for, holdout_params, segment_holdout

holdout_segments = segment_holdout      # the old name (one release)

Tensor = torch.Tensor

#: A later ``eps`` schedule whose best held-out error is still this many times the best so far
#: after its trial (``eps_trial`` frames x iterations, so short recordings, where it is cheap and
#: often wins, get many iterations) ends: it converges at each rank, which is slow on long ones.
#: Traced on 17 cases (observed hold-out only): where the 1e-4 schedule went on to win (343- to
#: 1200-frame HDM05 / CMU cuts) its best was 0.25-1.63x the 1e-2 schedule's after 100 iterations
#: and < 1.7x after its trial; where it did not win or by < 3 % (3000-6000-frame HDM05) 2.39-3.1x
#: after 50 iterations. The trial, ``eps_trial / T`` iterations and at least ``EPS_TRIAL_MIN``, is
#: >= 100 up to 1200 frames, where it won, and 30-40 from 3000 frames (see docs/speed.md).
EPS_TRIAL_RATIO = 1.7
#: Fewest iterations of a later schedule's trial.
EPS_TRIAL_MIN = 30
#: A later schedule is already stopped after a third of its trial (at least ``EPS_EARLY_MIN``
#: iterations) when its best held-out error is ``EPS_EARLY_RATIO`` times the best so far (traced:
#: experiments/results/tucker.md, "Early end of a losing schedule").
EPS_EARLY_RATIO = 2 * EPS_TRIAL_RATIO
#: Fewest iterations before the early check.
EPS_EARLY_MIN = 10


# ---------------------------------------------------------------------------------------------
# Block updates (one function per equation)
# ---------------------------------------------------------------------------------------------
def update_factor(ZG: Tensor, G: Tensor, A_n: Tensor, n: int, rho_a: float,
                  alpha_n: float) -> Tensor:
    """Eq. 17: ``A(n) = (Z_n G_(n)^T + rho_a A(n)_k)(G_(n) G_(n)^T + (alpha_n + rho_a) I)^-1``,
    then the Q factor of its thin QR. ``ZG = Z_n G_(n)^T`` with ``Z_n = unfold_n(X x_{m != n}
    A(m)^T)`` is given (see :func:`factor_sweep`)."""
    Gn = ops.unfold(G, n)
    rhs = ZG.add(A_n, alpha=rho_a)
    lhs = Gn @ Gn.T
    lhs.diagonal().add_(alpha_n + rho_a)
    A_new = rhs @ torch.linalg.inv(lhs)     # lhs: small, SPD (ridge >= rho_a); a product is faster
    return ops.orthonormalize(A_new)


def factor_sweep(X: Tensor, G: Tensor, A: list[Tensor], rho_a: float,
                 alpha: Sequence[float]) -> tuple[list[Tensor], Tensor]:
    """Eq. 17 for n = 1, 2, 3 in turn (Gauss-Seidel: ``Z_n`` uses the factors already updated).

    Returns the new factors and ``X x_1 A(1)^T x_2 A(2)^T x_3 A(3)^T`` for the core update
    (Eq. 18). The two products with the long time mode are single
    products of the temporal unfolding ``X_(1)`` (T x JK, a view): ``Z_1 G_(1)^T = X_(1) (A(2) kron
    A(3)) G_(1)^T`` (the small JK x R1 matrix first) and ``W_(1) = A(1)^T X_(1)``, shared by ``Z_2``,
    ``Z_3`` and the core.
    """
    A = list(A)
    T, J, K = X.shape
    X1 = X.reshape(T, J * K)
    ZG1 = X1 @ (torch.kron(A[1], A[2]) @ ops.unfold(G, 0).T)       # Z_1 G_(1)^T
    A[0] = update_factor(ZG1, G, A[0], 0, rho_a, alpha[0])
    W = (A[0].T @ X1).reshape(-1, J, K)                              # R1 x J x K
    Z2 = ops.unfold(ops.mode_dot(W, A[2].T, 2), 1)
    A[1] = update_factor(Z2 @ ops.unfold(G, 1).T, G, A[1], 1, rho_a, alpha[1])
    V = ops.mode_dot(W, A[1].T, 1)                                   # R1 x R2 x K
    Z3 = ops.unfold(V, 2)
    A[2] = update_factor(Z3 @ ops.unfold(G, 2).T, G, A[2], 2, rho_a, alpha[2])
    return A, ops.mode_dot(V, A[2].T, 2)


def update_core(XA: Tensor, G_k: Tensor, rho_g: float) -> Tensor:
    """Eq. 18: ``G = (X x_1 A(1)^T x_2 A(2)^T x_3 A(3)^T + rho_g G_k) / (1 + rho_g)``, given the
    projection ``XA = X x_1 A(1)^T x_2 A(2)^T x_3 A(3)^T``."""
    return (XA + rho_g * G_k) / (1.0 + rho_g)


def proximal_point(G: Tensor, A: Sequence[Tensor], X_k: Tensor, rho_x: float) -> Tensor:
    """``(G x A + rho_x X_k) / (1 + rho_x)``, the point Eqs. 19 and 24 pull ``X`` towards, as one
    product on the temporal unfolding: ``(A(1) [G x_2 A(2) x_3 A(3)]_(1) + rho_x X_k,(1)) /
    (1 + rho_x)`` (the full ``G x A`` is never formed)."""
    T = X_k.shape[0]
    B = ops.unfold(ops.mode_dot(ops.mode_dot(G, A[2], 2), A[1], 1), 0)   # R1 x JK
    P = torch.addmm(X_k.reshape(T, -1), A[0], B, beta=rho_x / (1.0 + rho_x), alpha=1.0 / (1.0 + rho_x))
    return P.reshape(X_k.shape)


def recover_tucker(P: Tensor, T_Omega: Tensor, gaps: Tensor) -> Tensor:
    """Eq. 19: ``X = P_Omega^c((G x A + rho_x X_k) / (1 + rho_x)) + P_Omega(T)``, given
    ``P = (G x A + rho_x X_k) / (1 + rho_x)`` (:func:`proximal_point`), ``T_Omega = P_Omega(T)``
    and the flat indices ``gaps`` of the entries outside ``Omega``: a copy of ``T_Omega`` with
    ``P`` written at ``gaps`` (the same values as ``torch.where(Omega, T, P)`` in a third of its
    time)."""
    X = T_Omega.clone()
    X.view(-1).index_copy_(0, gaps, P.reshape(-1).index_select(0, gaps))
    return X


def svt(M: Tensor, tau: float, method: str = "gram") -> Tensor:
    """``D_tau(M)`` (prox of ``tau ||.||_*``) through :func:`torchfill.ops.svt`; the matrix only."""
    return ops.svt(M, tau, method)[0]


def prox_tnn_closed_form(Z: Tensor, X_k: Tensor, rho_x: float, lam: float,
                         svd: str = "gram") -> Tensor:
    """Minimizer of Eq. 24, ``1/2||X - Z||^2 + rho_x/2 ||X - X_k||^2 + lam ||X||_*``, in closed form:
    ``D_{lam/(1+rho_x)}((Z + rho_x X_k) / (1 + rho_x))`` (complete the square)."""
    return svt((Z + rho_x * X_k) / (1.0 + rho_x), lam / (1.0 + rho_x), svd)


def prox_tnn_apg(Z: Tensor, X_k: Tensor, rho_x: float, lam: float, *, step: float = 1.0,
                 n_iter: int = 50, tol: float = 1e-10, svd: str = "gram") -> Tensor:
    """Eqs. 25-30 (Algorithm 1): accelerated proximal gradient for Eq. 24.

    ``f(X) = 1/2||X - Z||^2 + rho_x/2||X - X_k||^2`` has gradient ``(1 + rho_x) X - Z - rho_x X_k``
    and Lipschitz constant ``L = 1 + rho_x``. Iterates ``X_{j+1} = D_{lam s}(Y_j - s grad f(Y_j))``
    with step ``s = step / L``, ``t_{j+1} = (1 + sqrt(1 + 4 t_j^2)) / 2``,
    ``Y_{j+1} = X_{j+1} + (t_j - 1)/t_{j+1} (X_{j+1} - X_j)``, from ``X_0 = Y_0 = X_k``. With
    ``step = 1`` the first iterate is already the closed form.
    """
    L = 1.0 + rho_x
    s = step / L
    X = Y = X_k
    t = 1.0
    for _ in range(n_iter):
        grad = L * Y - Z - rho_x * X_k                               # Eq. 26
        X_new = svt(Y - s * grad, lam * s, svd)                      # Eq. 27
        t_new = (1.0 + math.sqrt(1.0 + 4.0 * t * t)) / 2.0           # Eq. 28
        Y = X_new + ((t - 1.0) / t_new) * (X_new - X)                # Eq. 29
        change = torch.linalg.norm(X_new - X) / torch.linalg.norm(X_new).clamp(min=1e-300)
        X, t = X_new, t_new
        if float(change) < tol:                                      # Eq. 30
            break
    return X


def increase_rank(A: list[Tensor], max_rank: Sequence[int], delta_rank: Sequence[int],
                  generator: torch.Generator) -> tuple[list[Tensor], bool]:
    """Eq. 31-32: every ``R_n < R_n^max`` grows by ``Delta R_n`` new random columns, re-orthonormalized."""
    grown, out = False, []
    for An, Rmax, dR in zip(A, max_rank, delta_rank):
        add = min(dR, Rmax - An.shape[1])
        if add > 0:
            new = torch.randn(An.shape[0], add, dtype=An.dtype, device=An.device, generator=generator)
            An = torch.linalg.qr(torch.cat([An, new], dim=1), mode="reduced").Q
            grown = True
        out.append(An)
    return out, grown


# ---------------------------------------------------------------------------------------------
# Solvers
# ---------------------------------------------------------------------------------------------
def _eps_list(value, owner: str) -> list[float]:
    values = [float(v) for v in (value if isinstance(value, (tuple, list)) else [value])]
    if not values or any(not v >= 0 for v in values):
        raise ValueError(f"{owner}: eps expected a float >= 0 or a list of them, found {value!r}")
    return values


def _triple(value, name: str, owner: str, cast=int) -> list:
    vals = [value] * 3 if isinstance(value, (int, float)) else list(value)
    if len(vals) != 3:
        raise ValueError(f"{owner}: {name} expected one number or three, found {value!r}")
    return [cast(v) for v in vals]


@register
class Tucker(Solver):
    """Tucker completion by proximal block coordinate descent (Mohaoui & Dmytryshyn 2026, Alg. 2).

    Each :meth:`step` updates the factors (Eq. 17), the core (Eq. 18), the recovered tensor
    (Eq. 19) and, when the observed residual stalls, the ranks (Eqs. 31-32). The rank and the
    returned iterate are chosen on held-out observed segments (see the module docstring), so
    nothing depends on the truth of the missing entries.

    Defaults are the same for every recording and apply to the internally normalized
    (unit-variance) data. Compared on the mean RMSE over three HDM05 recordings
    (hdm05_mm_01-02_03_120, hdm05_bd_05-01_01_120, HDM_bd_01-02_01_120) x multi_gap settings
    (gap, max gaps) = (100, 2), (100, 10), (200, 5), seed 0: ``holdout`` (on: 1.04 mm vs None,
    last iterate 1.05 mm for tucker; 1.95 vs 2.24 mm for tucker_tnn at lam_tnn=0.01) and ``lam_tnn``
    (0.1 / 0.01 / 0.001: 6.32 / 1.95 / 1.02 mm); the start (centroid-relative interpolation) on
    cmu_02_01, where plain interpolation left an edge gap 446 mm off (now 12 mm). ``rho_a``
    follows the paper's code; ``rho_g``, ``rho_x``, ``eps``, ``rank``, ``delta_rank``,
    ``patience`` and ``holdout_segments`` were set by hand (not tuned) for a ~100-iteration search.
    The shifted-gap hold-out (cap 5 % vs 10 %) and the two ``eps`` schedules were then chosen on
    nine cases (cmu_02_01 shared windows 10x100 and 20x50 and multi-gap 20x100x5, cmu_85_02 10x50,
    the first 1500 frames of hdm05_mm with 20x200x5, and four full-length HDM05 multi-gap cases):
    mean tucker_tnn RMSE 9.8 -> 2.5 mm, the short shared-window cases 29 -> 2 mm, the HDM05 cases
    at most 14 % worse, about twice the time.

    References
    ----------
    S. Mohaoui and A. Dmytryshyn, Tucker tensor completion for motion capture data, 2026.
    """

    name = "tucker"
    #: ``start``: an earlier fit's state on the same recording (:meth:`warm_start`), to start
    #: from instead of the interpolation; the rank search is then skipped.
    fit_data = ("start",)
    #: fill() computes in float32: on the Tucker Table 2 layout (HDM1/HDM2 x 9 cells, seed 0)
    #: tucker_tnn's mean RMSE 1.316 (float64) vs 1.203 mm (float32 better in 10 of 18 cells; with
    #: the constraints 0.985 vs 0.957) in half the time (270 vs 140 s); the mask suite's 19 cases
    #: 21.93 vs 21.93 (with the constraints). Rounding moves single cells either way (0.3-2.5x).
    fill_dtype = torch.float32
    params = {
        "max_iter": Param(800, int, low=1, doc="iteration cap (search over the eps schedules + refinement)"),
        "tol": Param(1e-4, float, low=0.0,
                     doc="refinement stops when the relative change of X is below (chosen: time vs accuracy)"),
        "rank": Param((8, 8, 3), (int, tuple, list),
                      doc="initial Tucker rank (R1, R2, R3) of the HOSVD start, capped by the shape"),
        "max_rank": Param((100, 40, 3), (int, tuple, list),
                          doc="R_max per mode (the paper's [100, 40, 3]), capped by the shape"),
        "delta_rank": Param((4, 2, 0), (int, tuple, list),
                            doc="Delta R_n added per rank increase (Eq. 31-32)"),
        "rho_a": Param(0.1, float, low=0.0, doc="proximal weight of the factors (Eq. 17; paper 0.1)"),
        "rho_g": Param(0.1, float, low=0.0, doc="proximal weight of the core (Eq. 18)"),
        "rho_x": Param(0.1, float, low=0.0, doc="proximal weight of the recovered tensor (Eq. 19)"),
        "alpha": Param(1e-3, (float, tuple, list), doc="alpha_n, ridge on the factors (Eq. 17), one or three"),
        "eps": Param((1e-2, 1e-4), (float, tuple, list),
                     doc="rank increase when |1 - r_k / r_{k-1}| <= eps (Eq. 31), r = observed residual. "
                         "Several values: the rank schedule runs once per value from the same start and "
                         "the held-out data choose (1e-2 suits long recordings with scattered gaps, 1e-4 "
                         "many markers missing at once in short ones, e.g. cmu_02_01)"),
        **holdout_params("shifted_gaps", 0.05, ", the paper's schedule and its last iterate"),
        "patience": Param(40, int, low=1,
                          doc="search ends this many iterations after the best validation error"),
        "eps_trial": Param(120_000, int, low=1,
                           doc="budget in frames x iterations: a later eps schedule ends after "
                               "max(30, eps_trial / T) iterations if its best held-out error is "
                               "still above EPS_TRIAL_RATIO times the best so far"),
    }

    renamed = {"rank_max": "max_rank", "val_segments": "holdout_segments",
               "val_length": "holdout_length"}
    renamed_attributes = {"tucker_": "decomposition_"}

    @classmethod
    def _upgrade(cls, kwargs: dict) -> dict:
        """``selection="last"`` (old) is ``holdout=None``; ``selection="holdout"`` the default."""
        if "selection" in kwargs:
            selection = kwargs.pop("selection")
            _deprecated(cls.name, "selection", "holdout=None" if selection == "last" else "holdout")
            if selection == "last":
                kwargs["holdout"] = None
            elif selection != "holdout":
                raise ValueError(f"{cls.name}: selection expected 'holdout' or 'last', found {selection!r}")
        return super()._upgrade(kwargs)

    # -- set-up -------------------------------------------------------------------------------
    def _initialize(self) -> None:
        shape = tuple(self.M_.shape)
        if len(shape) != 3:
            raise ValueError(f"{self.name}: expected a third-order tensor (T, J, 3), found {shape}")
        dims = list(shape)
        R_max = [min(r, d) for r, d in zip(_triple(self.max_rank, "max_rank", self.name), dims)]
        # a Tucker rank needs R_n <= prod of the others
        R_max = [min(R_max[n], math.prod(R_max[m] for m in range(3) if m != n)) for n in range(3)]
        R0 = [min(r, m) for r, m in zip(_triple(self.rank, "rank", self.name), R_max)]
        self.max_rank_ = R_max
        self.delta_rank_ = _triple(self.delta_rank, "delta_rank", self.name)
        self.alpha_ = _triple(self.alpha, "alpha", self.name, float)
        self.eps_candidates_ = _eps_list(self.eps, self.name)
        self.eps_ = self.eps_candidates_[0]
        self.R0_ = R0
        # held-out observed samples: hidden from the fit during the search phase
        start = self.fit_data_.get("start")
        self.start_ = None if start is None else self._units(*start)
        self.holdout_ = holdout_for(self) if start is None else HoldOut(self.Omega_, None)
        self.searching_ = self.holdout_.active
        self.search_end_iter_ = 0
        self._start(R0)
        self.schedule_best_ = (math.inf, 0)
        self.schedule_start_ = 0
        self.max_rank_full_ = list(self.max_rank_)

    @property
    def Omega_fit_(self) -> Tensor:
        """The observed entries the fit sees (all of them once the search has ended)."""
        return self.holdout_.fit_mask

    def _start(self, R: Sequence[int]) -> None:
        """Centroid-relative linear interpolation of the fitted gaps, then truncated HOSVD; or
        the given ``start`` (an earlier fit's recovered tensor and decomposition)."""
        if self.start_ is not None:
            X, G, A = self.start_
            self.X_ = torch.where(self.Omega_fit_, self.M_, X)
            self.decomposition_ = TuckerTensor(G.clone(), [a.clone() for a in A])
        else:
            self.X_ = self.interp_start(self.Omega_fit_, relative=True)
            self.decomposition_ = TuckerTensor.from_tensor(self.X_, R)
        self.residual_ = self._observed_residual(self.decomposition_())

    def _observed_residual(self, Y: Tensor) -> float:
        """``||P_Omega(Y - T)||`` over the entries the fit sees."""
        W, T_Omega, _ = self._fit_data()
        return float(torch.dist(Y * W, T_Omega))

    def _change(self, X: Tensor, X_k: Tensor) -> float:
        """``||X - X_k|| / ||X_k||``; both equal the data on the fitted entries, so only the others
        are compared."""
        i = self._fit_data()[2]
        diff = torch.dist(X.reshape(-1).index_select(0, i), X_k.reshape(-1).index_select(0, i))
        return float(diff / torch.linalg.vector_norm(X_k).clamp(min=1e-300))

    def _fit_data(self) -> tuple[Tensor, Tensor, Tensor]:
        """For the current fit mask (cached while it is the same): the mask as 0/1 weights, the
        data on it (0 elsewhere), and the flat indices of the entries it leaves out."""
        mask = self.Omega_fit_
        if getattr(self, "_fit_cache", (None,))[0] is not mask:
            W = mask.to(self.M_.dtype)
            self._fit_cache = (mask, W, (self.M_ * W).contiguous(),
                               (~mask).reshape(-1).nonzero().squeeze(1))
        return self._fit_cache[1:]

    # -- one iteration ------------------------------------------------------------------------
    def _recover(self, P: Tensor, X_k: Tensor, G: Tensor, A: list[Tensor]) -> Tensor:
        _, T_Omega, gaps = self._fit_data()
        return recover_tucker(P, T_Omega, gaps)                               # Eq. 19

    def step(self) -> dict[str, float]:
        with torch.no_grad():
            X_k, G_k = self.X_, self.decomposition_.core
            A = list(self.decomposition_.factors)
            A, XA = factor_sweep(X_k, G_k, A, self.rho_a, self.alpha_)        # Eq. 17
            G = update_core(XA, G_k, self.rho_g)                              # Eq. 18
            P = proximal_point(G, A, X_k, self.rho_x)           # (G x A + rho_x X_k) / (1 + rho_x)
            X = self._recover(P, X_k, G, A)                                   # Eq. 19 / 24-30
            # observed residual ||P_Omega(G x A - T)||: X_k = T on Omega, so G x A - T = (1+rho_x)(P - T)
            r = (1.0 + self.rho_x) * self._observed_residual(P)
            change = abs(1.0 - r / self.residual_) if self.residual_ > 0 else 0.0
            grown = False
            if change <= self.eps_:                                           # Eq. 31
                A, grown = increase_rank(A, self.max_rank_, self.delta_rank_, self.generator_)
                if grown:
                    G = ops.multi_mode_dot(X, A, transpose=True)     # Eq. 32, core recomputed
            delta = self._change(X, X_k)
            self.X_, self.residual_ = X, r
            self.decomposition_.core, self.decomposition_.factors = G, A
            info = {"delta": delta, "residual": r, "rank_change": change,
                    "R1": A[0].shape[1], "R2": A[1].shape[1], "R3": A[2].shape[1]}
            if self.searching_:
                info["holdout_rmse"] = self.holdout_.rmse(X, self.M_)
                self._select(info, self.n_iter_ + 1)
            return info

    # -- stopping / selection ---------------------------------------------------------------
    def _select(self, info: dict[str, float], it: int) -> None:
        """Search phase, after iteration ``it``: keep the best held-out iterate (over all
        schedules), and move to the next ``eps`` schedule or end the search when this one has
        stalled (``patience``) or converged at full rank."""
        val = info["holdout_rmse"]
        if self.holdout_.offer(val, self._snapshot, it):
            self.chosen_eps_ = self.eps_
        if val < self.schedule_best_[0]:              # best of this schedule: drives the patience
            self.schedule_best_ = (val, it)
        ranks_done = all(a.shape[1] >= m for a, m in zip(self.decomposition_.factors, self.max_rank_))
        stalled = it - self.schedule_best_[1] >= self.patience
        converged = ranks_done and info["delta"] < self.tol
        if self.schedule_start_ > 0:
            stalled |= self._losing(it - self.schedule_start_)
        if it >= self.max_iter - 1:
            self._end_search(it)
        elif stalled or converged:
            if len(self.eps_candidates_) > 1:
                self._next_schedule()
            else:
                self._end_search(it)

    def _losing(self, k: int) -> bool:
        """A later schedule, ``k`` iterations in, still far behind the best so far: after its
        trial (``eps_trial / T`` iterations, at least ``EPS_TRIAL_MIN``) above ``EPS_TRIAL_RATIO``
        times it, or after a third of the trial (at least ``EPS_EARLY_MIN``) above
        ``EPS_EARLY_RATIO`` times it."""
        trial = max(EPS_TRIAL_MIN, self.eps_trial // self.M_.shape[0])
        best, ours = self.holdout_.best_score, self.schedule_best_[0]
        if k >= trial:
            return ours > EPS_TRIAL_RATIO * best
        return k >= max(EPS_EARLY_MIN, trial // 3) and ours > EPS_EARLY_RATIO * best

    def _snapshot(self) -> tuple:
        return (self.X_.clone(), self.decomposition_.core.clone(),
                [a.clone() for a in self.decomposition_.factors], self.residual_)

    def should_stop(self, info: dict[str, float]) -> bool:
        """After the search (not in the iteration that ended it): relative change of X below ``tol``."""
        if self.searching_ or self.n_iter_ <= self.search_end_iter_:
            return False
        return info["delta"] < self.tol

    def _next_schedule(self) -> None:
        """Run the rank schedule again from the same start with the next ``eps``; the best
        validation error over all schedules is what ``_end_search`` restores."""
        self.eps_candidates_ = self.eps_candidates_[1:]
        self.eps_ = self.eps_candidates_[0]
        self.max_rank_ = list(self.max_rank_full_)
        self.schedule_best_ = (math.inf, self.n_iter_ + 1)
        self.schedule_start_ = self.n_iter_ + 1
        self._start(self.R0_)

    def _end_search(self, it: int) -> None:
        """Restore the iterate with the best held-out error, give the held-out data back,
        and continue at that rank (no further rank increases)."""
        X, G, A, _ = self.holdout_.release()
        self.searching_ = False
        self.search_end_iter_ = it
        self.X_ = torch.where(self.Omega_, self.M_, X)
        self.decomposition_.core, self.decomposition_.factors = G, A
        self.max_rank_ = [a.shape[1] for a in A]
        self.residual_ = self._observed_residual(ops.tucker_to_tensor(G, A))
        self.chosen_iter_ = self.holdout_.best_iter
        self.chosen_rank_ = tuple(a.shape[1] for a in A)

    def _estimate(self) -> Tensor:
        return self.X_

    def carry(self) -> dict:
        """The ``eps`` schedule whose iterate the hold-out chose: the next window runs only that
        one (bench_long 12 000 frames: the same RMSE in fewer iterations, see the README)."""
        eps = getattr(self, "chosen_eps_", None)
        return {"eps": [eps]} if eps is not None and len(_eps_list(self.eps, self.name)) > 1 else {}

    def warm_start(self) -> tuple[dict, dict]:
        """A refit at the rank this fit's hold-out chose (no search), from this fit's recovered
        tensor and decomposition (fit data ``start``, in the data's units): a few iterations
        where a fresh refit searches the ranks again (see docs/speed.md)."""
        rank = getattr(self, "chosen_rank_", None)
        if rank is None:
            return {}, {}
        d = self.decomposition_
        return ({"rank": rank, "max_rank": rank},
                {"start": (self.X_ * self.sigma_ + self.mu_, d.core * self.sigma_, list(d.factors))})

    def _units(self, X: Tensor, G: Tensor, A: list) -> tuple:
        """An earlier fit's state (data units) in this fit's normalized units. The core is
        rescaled to this fit's ``sigma_``; the shift of ``mu_`` between the two fits (the samples
        seen differ) is left to the first iterations."""
        return (((X.reshape(self.M_.shape) - self.mu_) / self.sigma_).to(self.M_.dtype),
                (G / self.sigma_).to(self.M_.dtype), [a.to(self.M_.dtype) for a in A])

    @property
    def rank_(self) -> tuple[int, ...]:
        return tuple(a.shape[1] for a in self.decomposition_.factors)


@register
class TuckerTNN(Tucker):
    """Tucker completion with a nuclear norm on the temporal unfolding (TuckerTNN, Eqs. 24-30).

    As :class:`Tucker`, but the recovery step minimizes
    ``1/2||X_(1) - Z||^2 + rho_x/2||X_(1) - X_(1),k||^2 + lam ||X_(1)||_*`` with
    ``Z = unfold_1(G x A)`` (Eq. 24), by its closed form (default) or by the paper's APG
    (``x_step="apg"``), then resets the observed entries. ``lam`` is relative to the data: the
    threshold is ``lam * sqrt(T)`` on the unit-variance data, so it means the same for any length.

    References
    ----------
    S. Mohaoui and A. Dmytryshyn, Tucker tensor completion for motion capture data, 2026.
    """

    name = "tucker_tnn"
    params = {
        "rho_x": Param(0.1, float, low=0.0, doc="proximal weight of X_(1) (Eq. 24)"),
        "lam_tnn": Param(0.001, float, low=0.0,
                     doc="nuclear-norm weight lambda, times sqrt(T) on the unit-variance data (Eq. 24)"),
        "x_step": Param("closed_form", str, choices=("closed_form", "apg"),
                        doc="X-step solver: the closed form D_{lam/(1+rho_x)} or the paper's APG"),
        "apg_step": Param(1.0, float, low=0.0, high=1.0, low_open=True,
                          doc="APG step as a fraction of 1/L, L = 1 + rho_x"),
        "apg_iter": Param(50, int, low=1, doc="APG iteration cap per X-step"),
        "svd": Param("gram", str, choices=("gram", "full"),
                     doc="SVT through the eigen-decomposition of the 3J x 3J Gram (fast) or a thin SVD"),
    }
    #: one name per idea: the temporal nuclear-norm weight is ``lam_tnn`` (as in grad_tucker)
    renamed = {"lam": "lam_tnn"}

    def _recover(self, P: Tensor, X_k: Tensor, G: Tensor, A: list[Tensor]) -> Tensor:
        T = P.shape[0]
        lam = self.lam_tnn * math.sqrt(T)
        if self.x_step == "apg":
            Z = ops.tucker_to_tensor(G, A).reshape(T, -1)                     # temporal unfolding
            X1 = prox_tnn_apg(Z, X_k.reshape(T, -1), self.rho_x, lam, step=self.apg_step,
                              n_iter=self.apg_iter, svd=self.svd)             # Eqs. 25-30
        else:   # Eq. 24 closed form D_{lam/(1+rho_x)}(P), P = (Z + rho_x X_k) / (1 + rho_x)
            X1 = svt(P.reshape(T, -1), lam / (1.0 + self.rho_x), self.svd)
        _, T_Omega, gaps = self._fit_data()
        return recover_tucker(X1.reshape(P.shape), T_Omega, gaps)            # reset observed
