"""Gradient fits of the Tucker and CP models by autograd: ``grad_tucker`` and ``grad_cp``.

The closed-form solvers (``tucker``, ``cp``) update a :class:`~torchfill.solvers.factorized.TuckerTensor`
or :class:`~torchfill.solvers.factorized.CPTensor` held as buffers; these solvers hold the very same
class with ``learn=True`` (its tensors are ``nn.Parameter``s) and minimize, with a ``torch.optim``
optimizer, the masked least-squares objective on the observed entries only::

    f = [ 1/2 ||P_Omega(X - T)||_F^2                      data fit on the observed set
          + lam_tnn * s * ||X_(1)||_*                     temporal nuclear norm (TuckerTNN's prior)
          + lam_smooth/2 * ||X x_1 D_k||_F^2              temporal smoothness of the time factor
          + lam_l1 * s * sum_n ||A(n)||_1 ] / |Omega|     l1 on the factors (SparseCP's prior)

with ``X`` the model tensor (G x_1 A(1) x_2 A(2) x_3 A(3), or sum_r w_r a_r(1) o a_r(2) o a_r(3)),
``T`` the normalized data, ``X_(1)`` the T x 3J temporal unfolding, ``D_k`` the first (k=1) or second
(k=2) temporal difference (``X x_1 D_k`` is the model with its time factor A(1) replaced by
``D_k A(1)``: a penalty on the time factor, weighted by what the other factors carry), and
``s = ||P_Omega T||_F`` (= sqrt(|Omega|) after the base's normalization) so that ``lam_tnn`` and
``lam_l1`` are thresholds relative to the norm of the data. Every weight is dimensionless.

``step()`` is ONE optimizer step (Adam, or one L-BFGS iteration with a strong-Wolfe line search),
followed by a retraction that keeps the model exact: Tucker factors are re-orthonormalized by a thin
QR, ``A = QR``, with ``R`` absorbed into the core (``G x_n R``), so the tensor is unchanged; CP
columns are scaled to unit norm with the norms moved into the weights. The QR retraction was chosen
over ``torch.nn.utils.parametrizations.orthogonal`` on measurements (wave 1,
experiments/results/autograd.md): with Adam both reach the same error (1.1e-3) but the
parametrization costs about twice the time per step (Householder products in every forward and
backward pass); with L-BFGS the QR retraction reaches 7e-5 and the parametrization only 6e-2 in
1000 steps. The QR model is also a plain module whose state_dict loads into a fresh TuckerTensor.
``ortho="param"`` stays available (the parametrization is removed at the end of ``fit``).

Stopping is honest: on the observed objective (relative decrease over ``patience`` steps below
``tol``), or on a held-out set of OBSERVED samples (``holdout="runs"``: gap-shaped runs of observed
samples removed from the fit; the iterate with the lowest held-out error is kept). The truth of the
missing entries is never seen.

References
----------
S. Mohaoui, A. Dmytryshyn, "Tucker tensor completion with temporal nuclear norm for motion capture
gap filling", 2026 (the Tucker model, TuckerTNN's prior, the multi-gap protocol).
S. Mohaoui, A. Dmytryshyn, "CP decomposition-based algorithms for completion problem of motion
capture data", 2024 (CP, SmoothCP, SparseCP priors).
D. P. Kingma, J. Ba, "Adam: a method for stochastic optimization", ICLR 2015.
D. C. Liu, J. Nocedal, "On the limited memory BFGS method for large scale optimization", Math.
Program. 45, 1989.
J. Kossaifi et al., "TensorLy-Torch" (factorized tensors as modules holding parameters or buffers).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn
from torch.nn.utils import parametrizations, parametrize

from .. import ops
from .base import Param, Solver, _deprecated, available, get_solver, register
from .factorized import CPTensor, TuckerTensor
from .holdout import holdout_for, holdout_params, run_holdout

holdout_runs = run_holdout      # the old name (one release)

Tensor = torch.Tensor


# ---------------------------------------------------------------------------------------------
# The objective: pure functions of tensors (gradcheck-able)
# ---------------------------------------------------------------------------------------------
def penalized_loss(X: Tensor, X_diff: Tensor | None, factors: Sequence[Tensor], M: Tensor,
                   Omega: Tensor, *, lam_tnn: float = 0.0, lam_smooth: float = 0.0,
                   lam_l1: float = 0.0, scale: float | Tensor | None = None) -> Tensor:
    """The objective ``f`` of the module docstring, from the model tensor and its parts.

    Parameters
    ----------
    X : Tensor (T, J, 3)
        The model tensor.
    X_diff : Tensor or None
        The model with its time factor replaced by ``D_k A(1)`` (needed when ``lam_smooth > 0``).
    factors : sequence of Tensor
        The factor matrices (for the l1 term).
    M, Omega : Tensor
        Normalized data (zeros at missing entries) and the observed set (bool), same shape as ``X``.
    lam_tnn, lam_smooth, lam_l1 : float
        Weights of the temporal nuclear norm, the temporal smoothness and the l1 terms.
    scale : float, optional
        ``s``, the norm the thresholds are relative to; default ``||P_Omega M||_F``.
    """
    n_obs = Omega.sum()
    R = torch.where(Omega, X - M, torch.zeros((), dtype=X.dtype, device=X.device))
    f = 0.5 * (R * R).sum()                                            # 1/2 ||P_Omega(X - T)||^2
    if scale is None:
        scale = torch.linalg.vector_norm(torch.where(Omega, M, torch.zeros_like(M)))
    if lam_tnn > 0:
        f = f + lam_tnn * scale * torch.linalg.svdvals(X.reshape(X.shape[0], -1)).sum()   # ||X_(1)||_*
    if lam_smooth > 0 and X_diff is not None:
        f = f + 0.5 * lam_smooth * (X_diff * X_diff).sum()             # ||X x_1 D_k||^2
    if lam_l1 > 0:
        f = f + lam_l1 * scale * sum(A.abs().sum() for A in factors)
    return f / n_obs


def _model_loss(to_tensor, head: Tensor, factors: Sequence[Tensor], M: Tensor, Omega: Tensor,
                smooth_order: int, weights: dict) -> Tensor:
    X = to_tensor(head, factors)
    X_diff = None
    if weights.get("lam_smooth", 0.0) > 0:          # the model with its time factor D_k A(1)
        X_diff = to_tensor(head, [ops.difference(factors[0], smooth_order), *factors[1:]])
    return penalized_loss(X, X_diff, factors, M, Omega, **weights)


def tucker_loss(G: Tensor, factors: Sequence[Tensor], M: Tensor, Omega: Tensor, *,
                smooth_order: int = 1, **weights) -> Tensor:
    """``f`` for the Tucker model ``G x_1 A(1) x_2 A(2) x_3 A(3)`` (see :func:`penalized_loss`)."""
    return _model_loss(ops.tucker_to_tensor, G, factors, M, Omega, smooth_order, weights)


def cp_loss(w: Tensor, factors: Sequence[Tensor], M: Tensor, Omega: Tensor, *,
            smooth_order: int = 1, **weights) -> Tensor:
    """``f`` for the CP model ``sum_r w_r a_r(1) o a_r(2) o a_r(3)`` (see :func:`penalized_loss`)."""
    return _model_loss(ops.cp_to_tensor, w, factors, M, Omega, smooth_order, weights)


# ---------------------------------------------------------------------------------------------
# Starts and ranks (observed data only)
# ---------------------------------------------------------------------------------------------
def energy_rank(X: Tensor, mode: int, energy: float) -> int:
    """The energy rank (:func:`torchfill.ops.energy_rank`) of ``unfold(X, mode)`` (applied to the
    interpolation-filled data, never to complete data)."""
    return ops.energy_rank(ops.unfold(X, mode), energy)


def _find_model(solver: Solver, kind: type) -> nn.Module:
    """The closed-form solver's factorized tensor (its learned ``*_`` attribute of type ``kind``)."""
    value = getattr(solver, "decomposition_", None)
    if isinstance(value, kind):
        return value
    found = [k for k, v in vars(solver).get("_modules", {}).items() if isinstance(v, kind)]
    if found:
        return getattr(solver, found[0])
    raise ValueError(f"{solver.name}: no {kind.__name__} found to start from")


# ---------------------------------------------------------------------------------------------
# The solvers
# ---------------------------------------------------------------------------------------------
class _GradientFit(Solver):
    """Shared loop of the autograd solvers: optimizer, schedule, retraction, honest stopping."""

    params = {
        "max_iter": Param(2000, int, low=1, doc="optimizer steps cap (an L-BFGS step is one iteration "
                          "with its line search)"),
        "tol": Param(1e-5, float, low=0.0, doc="stop when the objective (or the held-out error) "
                     "improved by less than this fraction over the last `patience` steps"),
        "patience": Param(50, int, low=1, doc="window of the stopping rule, in steps (the plateau "
                          "schedule uses patience // 5); a round number, not tuned"),
        "optimizer": Param("adam", str, choices=("adam", "lbfgs"), doc="torch.optim optimizer"),
        "lr": Param(None, float, low=0.0, low_open=True, allow_none=True,
                    doc="Adam: step relative to each parameter's RMS at the start (default 0.01, "
                    "the usual Adam step made scale free; not tuned per file), halved whenever "
                    "the objective plateaus for patience // 5 steps. L-BFGS: initial step "
                    "(default 1) of its strong-Wolfe line search"),
        "init": Param("hosvd", str, choices=("hosvd", "closed_form"),
                      doc="warm start: the interpolation-filled data's truncated HOSVD (CP: a "
                      "CP-ALS fit of it), or the registered closed-form solver's fit"),
        "init_params": Param(None, dict, allow_none=True,
                             doc="hyperparameters of the closed-form solver of init='closed_form'"),
        "lam_tnn": Param(0.0, float, low=0.0, doc="temporal nuclear norm weight (relative to "
                         "||P_Omega T||)"),
        "lam_smooth": Param(0.0, float, low=0.0, doc="temporal smoothness weight (relative to the "
                            "data term, per entry)"),
        "smooth_order": Param(1, int, choices=(1, 2), doc="difference order of the smoothness term"),
        "lam_l1": Param(0.0, float, low=0.0, doc="l1 weight on the factors (relative to "
                        "||P_Omega T||)"),
        **holdout_params(None, 0.1, ", stop on the observed objective (with a hold-out the fit "
                                    "stops on the held-out error and keeps the best iterate)"),
    }
    renamed_attributes = {"model_": "decomposition_"}

    @classmethod
    def _upgrade(cls, kwargs: dict) -> dict:
        """``holdout=<share>`` (old, a float) is ``holdout="runs", holdout_share=<share>``."""
        old = kwargs.get("holdout")
        if isinstance(old, (int, float)) and not isinstance(old, bool):
            new = "runs" if old > 0 else None
            _deprecated(cls.name, f"holdout={old}", f"holdout={new!r}, holdout_share={old}")
            kwargs["holdout"] = new
            if old > 0:
                kwargs.setdefault("holdout_share", float(old))
        return super()._upgrade(kwargs)

    #: default relative Adam step (see the ``lr`` doc)
    adam_lr = 1e-2

    # -- model-specific ------------------------------------------------------------------------
    def _build(self, X0: Tensor) -> nn.Module:
        raise NotImplementedError

    def _loss(self, Omega: Tensor) -> Tensor:
        raise NotImplementedError

    def _retract(self) -> None:
        """Re-normalize the factors without changing the model tensor (under no_grad)."""

    # -- contract ------------------------------------------------------------------------------
    def _initialize(self) -> None:
        M = self.M_
        self.holdout_ = holdout_for(self)
        self.decomposition_ = self._start()
        self.scale_ = torch.linalg.vector_norm(torch.where(self.fit_mask_, M, torch.zeros_like(M))).detach()
        self.optimizer_ = self._make_optimizer()
        self.loss_scale_ = float(self.fit_mask_.sum()) if self.optimizer == "lbfgs" else 1.0
        self.prev_X_ = None
        self.losses_: list[float] = []
        self._plateau = 0

    def _start(self) -> nn.Module:
        X0 = self.interp_start(self.fit_mask_)     # gaps (and held-out samples) interpolated
        if self.init == "closed_form":
            return self._closed_form_start(X0)
        return self._build(X0)

    def _closed_form_start(self, X0: Tensor) -> nn.Module:
        name = self.closed_form_name
        if name not in available():
            raise ValueError(f"{self.name}: init='closed_form' needs the registered solver "
                             f"{name!r}; found only {available()}")
        Xn = torch.where(self.fit_mask_, self.M_, torch.full_like(self.M_, float("nan")))
        cf = get_solver(name, **{"seed": self.seed, **(self.init_params or {})}).fit(Xn)
        return self._from_closed_form(cf)

    def _make_optimizer(self) -> torch.optim.Optimizer:
        params = [p for p in self.decomposition_.parameters() if p.requires_grad]
        if self.optimizer == "lbfgs":
            return torch.optim.LBFGS(params, lr=self.lr or 1.0, max_iter=1, max_eval=25, history_size=20,
                                     line_search_fn="strong_wolfe", tolerance_grad=0.0,
                                     tolerance_change=0.0)   # stopping is ours (observed data)
        lr = self.lr or self.adam_lr
        groups = [{"params": [p], "lr": lr * float(p.detach().pow(2).mean().sqrt().clamp(min=1e-8)),
                   "lr0": None} for p in params]
        for g in groups:
            g["lr0"] = g["lr"]
        return torch.optim.Adam(groups)

    @property
    def fit_mask_(self) -> Tensor:
        """The observed entries the objective sees (the held-out ones excluded)."""
        return self.holdout_.fit_mask

    @property
    def holdout_mask_(self) -> Tensor | None:
        """The held-out observed entries (None: no hold-out)."""
        return self.holdout_.V

    def step(self) -> dict[str, float]:
        """One optimizer step on the observed objective, then the retraction."""
        opt = self.optimizer_
        params = [p for g in opt.param_groups for p in g["params"]]

        def closure() -> Tensor:
            opt.zero_grad(set_to_none=True)
            with torch.enable_grad():
                loss = self._loss(self.fit_mask_)
                # L-BFGS on the un-normalized sum: torch's LBFGS skips curvature pairs with
                # y's < 1e-10 (absolute), which the per-entry mean reaches near convergence
                (loss * self.loss_scale_).backward()
            for p in params:                   # L-BFGS flattens with .view(): needs contiguous grads
                if p.grad is not None and not p.grad.is_contiguous():
                    p.grad = p.grad.contiguous()
            return loss * self.loss_scale_

        loss = opt.step(closure) / self.loss_scale_
        with torch.no_grad():
            self._retract()
            X = self._tensor()
            info = {"loss": float(loss.detach())}
            if self.prev_X_ is not None:
                info["delta"] = float(torch.linalg.vector_norm(X - self.prev_X_)
                                      / torch.linalg.vector_norm(self.prev_X_).clamp(min=1e-300))
            self.prev_X_ = X
            R = torch.where(self.fit_mask_, X - self.M_, torch.zeros_like(X))
            info["fit"] = float(torch.linalg.vector_norm(R) / self.scale_)   # relative observed residual
            if self.holdout_.active:
                info["holdout_rmse"] = self.holdout_.rmse(X, self.M_)
                self.holdout_.offer(info["holdout_rmse"], self._snapshot, self.n_iter_ + 1)
            info["lr"] = float(opt.param_groups[0]["lr"])
        self.losses_.append(info["holdout_rmse"] if self.holdout_.active else info["loss"])
        self._schedule()
        return info

    def _schedule(self) -> None:
        """Adam: halve every step size when the objective has not improved by ``tol`` (relative)
        over the last ``patience // 5`` steps (a plateau schedule needing no per-file tuning)."""
        if self.optimizer != "adam":
            return
        window = max(2, self.patience // 5)
        self._plateau += 1
        if self._plateau >= window and len(self.losses_) > window:
            old, new = self.losses_[-window - 1], min(self.losses_[-window:])
            if old - new <= self.tol * abs(old):
                for g in self.optimizer_.param_groups:
                    g["lr"] *= 0.5
            self._plateau = 0

    def should_stop(self, info: dict[str, float]) -> bool:
        """Stop when the watched value (the objective, or the held-out error) improved by less than
        ``tol`` (relative) over the last ``patience`` steps, or Adam's steps fell below 1e-3 of
        their start. Observed data only."""
        L = self.losses_
        if not all(math.isfinite(v) for v in L[-1:]):
            return True
        if self.optimizer == "adam":
            g = self.optimizer_.param_groups[0]
            if g["lr"] < 1e-3 * g["lr0"]:
                return True
        if len(L) <= self.patience:
            return False
        old, new = min(L[:-self.patience]), min(L[-self.patience:])
        return old - new <= self.tol * abs(old)

    def finalize(self) -> None:
        """End of fit: restore the best held-out iterate (if any), drop the optimizer state and any
        parametrization, so that ``decomposition_`` is a plain TuckerTensor / CPTensor."""
        if self.holdout_.best_state is not None:
            with torch.no_grad():
                self.decomposition_.load_state_dict(self.holdout_.best_state)
            self.chosen_iter_ = self.holdout_.best_iter
        for name in list(getattr(self.decomposition_, "parametrizations", {}) or {}):
            parametrize.remove_parametrizations(self.decomposition_, name, leave_parametrized=True)
        self.prev_X_ = None

    @property
    def rank_(self) -> tuple[int, ...]:
        """The rank of the fitted model: (R1, R2, R3) for Tucker, (R,) for CP."""
        return self.decomposition_.rank

    def _snapshot(self) -> dict[str, Tensor]:
        return {k: v.detach().clone() for k, v in self.decomposition_.state_dict().items()}

    def _estimate(self) -> Tensor:
        with torch.no_grad():
            return self._tensor().detach()

    def _weights(self) -> dict[str, float]:
        return {"lam_tnn": self.lam_tnn, "lam_smooth": self.lam_smooth, "lam_l1": self.lam_l1,
                "smooth_order": self.smooth_order}


@register
class GradTucker(_GradientFit):
    """Tucker completion by gradient descent on the observed objective (autograd).

    The model is a :class:`TuckerTensor` with ``learn=True`` (core and factors are parameters); the
    factors stay column-orthonormal (QR retraction, or ``ortho="param"``:
    ``torch.nn.utils.parametrizations.orthogonal``). After ``fit``, ``decomposition_`` is a plain
    ``nn.Module`` a user can keep training in a loop of their own.

    Ranks ``(R1, R2, R3)``: given, or by the energy rule on the interpolation-filled data (the
    smallest rank holding ``energy`` of each unfolding's energy), capped by ``max_rank``.

    References
    ----------
    S. Mohaoui, A. Dmytryshyn, Tucker tensor completion with temporal nuclear norm for motion
    capture gap filling, 2026 (model, Eq. 19 data term; TuckerTNN prior, Eqs. 24-30).
    """

    name = "grad_tucker"
    closed_form_name = "tucker"
    params = {
        "rank": Param(None, (int, tuple, list), allow_none=True,
                      doc="(R1, R2, R3), or one int for (R, R, 3); None: energy rule"),
        "energy": Param(0.999, float, low=0.0, high=1.0, low_open=True,
                        doc="energy kept by the rank rule (0.999: a conventional level, not tuned; "
                        "see experiments/results/autograd.md for what it gives)"),
        "max_rank": Param(40, int, low=1, doc="cap of R1, R2 under the energy rule"),
        "ortho": Param("qr", str, choices=("qr", "param", "none"),
                       doc="orthonormal factors: QR retraction, orthogonal parametrization, or free"),
    }

    def _ranks(self, X0: Tensor) -> tuple[int, ...]:
        shape = X0.shape
        if self.rank is None:
            rank = [min(energy_rank(X0, n, self.energy), self.max_rank) for n in range(X0.ndim)]
        elif isinstance(self.rank, int):
            rank = [self.rank] * (X0.ndim - 1) + [shape[-1]]
        else:
            rank = list(self.rank)
            if len(rank) != X0.ndim:
                raise ValueError(f"{self.name}: rank expected {X0.ndim} ints, found {self.rank!r}")
        return tuple(max(1, min(int(R), int(I), math.prod(shape) // int(I))) for R, I in zip(rank, shape))

    def _build(self, X0: Tensor) -> nn.Module:
        return self._orthogonal(TuckerTensor.from_tensor(X0, self._ranks(X0), learn=True))

    def _wrap(self, G: Tensor, factors: Sequence[Tensor]) -> TuckerTensor:
        return self._orthogonal(TuckerTensor(G.detach().clone(), [A.detach().clone() for A in factors],
                                             learn=True))

    def _orthogonal(self, model: TuckerTensor) -> TuckerTensor:
        if self.ortho == "param":
            for n in range(model.n_modes):
                if model.factors[n].shape[1] > 1 or model.factors[n].shape[0] > 1:
                    parametrizations.orthogonal(model, f"factor_{n}")
        return model

    def _from_closed_form(self, cf: Solver) -> nn.Module:
        src = _find_model(cf, TuckerTensor)
        G, factors = src.core, src.factors
        X = ops.tucker_to_tensor(G, factors)
        Q = [ops.orthonormalize(A) for A in factors]
        return self._wrap(ops.multi_mode_dot(X, Q, transpose=True), Q)

    def _tensor(self) -> Tensor:
        return ops.tucker_to_tensor(self.decomposition_.core, self.decomposition_.factors)

    def _loss(self, Omega: Tensor) -> Tensor:
        m = self.decomposition_
        return tucker_loss(m.core, m.factors, self.M_, Omega, scale=self.scale_, **self._weights())

    def _retract(self) -> None:
        """``A(n) = Q R`` (thin QR), ``G <- G x_n R``: orthonormal factors, same tensor."""
        if self.ortho != "qr":
            return
        m = self.decomposition_
        G = m.core.detach()
        for n, A in enumerate(m.factors):
            Q, R = torch.linalg.qr(A.detach(), mode="reduced")
            s = torch.sign(torch.diagonal(R))
            s = torch.where(s == 0, torch.ones_like(s), s)       # unique QR: diag(R) >= 0
            Q, R = Q * s, R * s.unsqueeze(1)
            A.copy_(Q)
            G = torch.movedim(torch.tensordot(R, G, dims=([1], [n])), 0, n)   # G x_n R
        m.core.copy_(G)


@register
class GradCP(_GradientFit):
    """CP completion by gradient descent on the observed objective (autograd).

    The model is a :class:`CPTensor` with ``learn=True``; after each step the factor columns are
    scaled to unit norm and the norms moved into the weights (the tensor is unchanged), as in the
    CP paper's normalized factors, which gives the l1 prior a fixed scale. Start: a CP-ALS fit
    (TensorLy ``parafac``, SVD init, 50 sweeps) of the interpolation-filled data.

    Rank ``R``: given, or ``rank_factor`` times the time rank of the Tucker energy rule (a CP
    needs more components than the multilinear rank), capped by ``max_rank``.

    References
    ----------
    S. Mohaoui, A. Dmytryshyn, CP decomposition-based algorithms for completion problem of motion
    capture data, 2024 (model Eq. 22-26; SmoothCP Eq. 32-33; SparseCP Eq. 34-35).
    """

    name = "grad_cp"
    closed_form_name = "cp"
    params = {
        "rank": Param(None, int, low=1, allow_none=True, doc="R; None: rule below"),
        "energy": Param(0.999, float, low=0.0, high=1.0, low_open=True,
                        doc="energy kept by the time-rank rule"),
        "rank_factor": Param(2.0, float, low=0.0, low_open=True,
                             doc="R = rank_factor x time rank (2: a CP needs more terms than the "
                             "multilinear rank; not tuned)"),
        "max_rank": Param(60, int, low=1, doc="cap of R under the rule"),
    }

    def _build(self, X0: Tensor) -> nn.Module:
        R = self.rank
        if R is None:
            R = min(self.max_rank, max(1, round(self.rank_factor * energy_rank(X0, 0, self.energy))))
        model = CPTensor.from_tensor(X0, R, seed=self.seed, learn=True)
        with torch.no_grad():
            self._normalize(model)
        return model

    def _wrap(self, w: Tensor, factors: Sequence[Tensor]) -> CPTensor:
        model = CPTensor(w.detach().clone(), [A.detach().clone() for A in factors], learn=True)
        with torch.no_grad():
            self._normalize(model)
        return model

    def _from_closed_form(self, cf: Solver) -> nn.Module:
        src = _find_model(cf, CPTensor)
        return self._wrap(src.weights, src.factors)

    def _tensor(self) -> Tensor:
        return ops.cp_to_tensor(self.decomposition_.weights, self.decomposition_.factors)

    def _loss(self, Omega: Tensor) -> Tensor:
        m = self.decomposition_
        return cp_loss(m.weights, m.factors, self.M_, Omega, scale=self.scale_, **self._weights())

    @staticmethod
    def _normalize(model: CPTensor) -> None:
        w = model.weights.detach().clone()
        for A in model.factors:
            norms = torch.linalg.vector_norm(A.detach(), dim=0).clamp(min=1e-300)
            A.copy_(A.detach() / norms)
            w = w * norms
        model.weights.copy_(w)

    def _retract(self) -> None:
        """Unit-norm factor columns, norms into the weights: same tensor."""
        self._normalize(self.decomposition_)
