"""The Lightning drivers: one training_step = one solver step, same result as a plain fit, stopping
on the solver's own rule, and no way for the truth to reach a solver."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchfill.lightning import (CaseDataModule, Convergence, Evaluation, SolverModule, fit,
                                 observed_view)
from torchfill import metrics
from torchfill.solvers.base import Param, Solver


class HardImpute(Solver):
    """Rank-r SVD imputation of the T x 3J unfolding (not registered): a cheap iterative solver."""

    name = "hard_impute_test"
    params = {"rank": Param(2, int, low=1)}

    def _initialize(self):
        self.X_ = self.interp_start()

    def step(self):
        T = self.M_.shape[0]
        U, s, Vh = torch.linalg.svd(self.X_.reshape(T, -1), full_matrices=False)
        L = ((U[:, :self.rank] * s[:self.rank]) @ Vh[:self.rank]).reshape(self.M_.shape)
        X = torch.where(self.Omega_, self.M_, L)
        delta = float(torch.linalg.norm(X - self.X_) / torch.linalg.norm(self.X_))
        self.X_ = X
        return {"delta": delta, "objective": float(torch.linalg.norm((L - self.M_)[self.Omega_]))}

    def _estimate(self):
        return self.X_


class Spy(HardImpute):
    """Records exactly what it is given."""

    name = "spy_test"

    def initialize(self, X, mask=None):
        self.received = (X, mask)
        return super().initialize(X, mask)


def low_rank_case(T=120, J=12, rank=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    t = torch.linspace(0, 1, T, dtype=torch.float64)[:, None]
    basis = torch.cat([torch.sin(2 * math.pi * t * (k + 1)) for k in range(rank)], dim=1)
    truth = (basis @ torch.randn(rank, 3 * J, generator=g, dtype=torch.float64)).reshape(T, J, 3)
    truth = truth * 100 + 500
    mask = np.zeros((T, J), dtype=bool)
    mask[30:60, 1] = mask[70:100, 4] = mask[10:25, 6] = True
    return truth.numpy(), mask


def test_trainer_fit_equals_plain_fit_and_stops_on_solver_rule():
    truth, mask = low_rank_case()
    plain = HardImpute(rank=3, tol=1e-8, max_iter=2000)
    X = np.where(mask[..., None], np.nan, truth)
    expected = plain.fit_transform(torch.as_tensor(X))
    solver = HardImpute(rank=3, tol=1e-8, max_iter=2000)
    stop = Convergence()
    module = fit(solver, CaseDataModule(truth, mask, n_steps=solver.max_iter), callbacks=[stop])
    assert stop.reason == "converged" and solver.converged_
    assert solver.n_iter_ == plain.n_iter_ < 2000
    assert [h["delta"] for h in solver.history_] == [h["delta"] for h in plain.history_]
    torch.testing.assert_close(module.filled(), expected, rtol=0, atol=0)
    # rank-2 data plus the mean removed by centring: a rank-3 fit are recovered to high accuracy
    assert metrics.rmse_missing(module.filled().numpy(), truth, mask) < 1e-3


def test_max_iter_caps_the_trainer():
    truth, mask = low_rank_case()
    solver = HardImpute(rank=1, tol=0.0, max_iter=7)
    stop = Convergence()
    fit(solver, CaseDataModule(truth, mask, n_steps=solver.max_iter), callbacks=[stop])
    assert solver.n_iter_ == 7 and len(solver.history_) == 7 and stop.reason == "max_iter"


def test_early_stopping_on_observed_objective():
    truth, mask = low_rank_case()
    solver = HardImpute(rank=2, tol=0.0, max_iter=500)
    stop = Convergence(monitor="objective", patience=3, min_delta=0.5)
    fit(solver, CaseDataModule(truth, mask, n_steps=solver.max_iter), callbacks=[stop])
    assert stop.reason == "objective stalled" and 4 <= solver.n_iter_ < 500


def test_evaluation_callback_curve_and_final_score():
    truth, mask = low_rank_case()
    solver = HardImpute(rank=2, tol=1e-6, max_iter=100)
    ev = Evaluation(every=1)
    module = fit(solver, CaseDataModule(truth, mask, n_steps=solver.max_iter), callbacks=[ev])
    assert [c["iter"] for c in ev.curve] == list(range(1, solver.n_iter_ + 1))
    assert ev.final == metrics.score(module.filled().numpy(), truth, mask)
    assert ev.curve[-1]["rmse"] == pytest.approx(ev.final["rmse"])
    assert ev.curve[-1]["rmse"] < ev.curve[0]["rmse"]          # iterating helps on low-rank data


def test_solver_never_receives_the_truth_from_the_datamodule():
    truth, mask = low_rank_case()
    dm = CaseDataModule(truth, mask, n_steps=5)
    assert set(dm.observed_batch()) == {"X", "mask"}
    spy = Spy(rank=2, max_iter=5)
    fit(spy, dm)
    X, got_mask = spy.received
    m = torch.as_tensor(mask)
    assert torch.isnan(X[m]).all() and torch.isfinite(X[~m]).all()
    assert torch.equal(X[~m], torch.as_tensor(truth)[~m])
    assert torch.equal(got_mask, m)
    assert X.data_ptr() != dm.evaluation_truth().data_ptr()


def test_truth_bearing_batch_is_stripped_before_the_solver():
    """Even a batch whose X carries the truth at the gaps (plus a 'truth' entry) cannot leak it."""
    truth, mask = low_rank_case()
    T = torch.as_tensor(truth)
    batch = {"X": T.clone(), "mask": torch.as_tensor(mask), "truth": T}
    spy = Spy(rank=2, max_iter=3)
    module = SolverModule(spy)
    module.training_step(batch, 0)
    X, _ = spy.received
    m = torch.as_tensor(mask)
    assert torch.isnan(X[m]).all()
    assert X.data_ptr() not in (T.data_ptr(), batch["X"].data_ptr())
    # and the solver's own normalized data is zero at the gaps
    assert (spy.M_[m] == 0).all() and not spy.Omega_[m].any()
    Xo, _ = observed_view(batch)
    assert torch.isnan(Xo[m]).all() and torch.equal(Xo[~m], T[~m])


def test_datamodule_rejects_mismatched_mask():
    truth, mask = low_rank_case()
    with pytest.raises(ValueError, match="expected truth"):
        CaseDataModule(truth, mask[:-1])
