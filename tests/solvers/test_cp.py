"""CP, SmoothCP and SparseCP (Mohaoui & Dmytryshyn 2024): recovery, priors, real-data accuracy."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.solvers import get_solver
from torchfill.ops import difference_gram
from torchfill.solvers.cp import leading_rank_one
from torchfill.solvers.holdout import shifted_gap_holdout


def _cp_tensor(shape, R, seed=0):
    g = torch.Generator().manual_seed(seed)
    factors = [torch.randn(n, R, generator=g, dtype=torch.float64) for n in shape]
    return torch.einsum("ir,jr,kr->ijk", *factors)


def _load(path):
    """(T, J, 3) points, labels starting with '*' (HDM05 duplicates) dropped."""
    seq = torchfill.read(path)
    keep = [i for i, lab in enumerate(seq.labels) if not str(lab).startswith("*")]
    return np.asarray(seq.points, dtype=np.float64)[:, keep]


def test_difference_gram_matches_dense_operator():
    a = torch.randn(7, dtype=torch.float64)
    D = torch.diff(torch.eye(7, dtype=torch.float64), dim=0)
    torch.testing.assert_close(difference_gram(a), D.T @ D @ a)


def test_leading_rank_one_recovers_a_rank_one_tensor():
    a, b, c = torch.randn(30, dtype=torch.float64), torch.randn(8, dtype=torch.float64), \
        torch.randn(3, dtype=torch.float64)
    E = torch.einsum("i,j,k->ijk", a, b, c)
    lam, (a1, a2, a3) = leading_rank_one(E)
    torch.testing.assert_close(lam * torch.einsum("i,j,k->ijk", a1, a2, a3), E)


@pytest.mark.parametrize("holdout", [False, True])
def test_cp_recovers_synthetic_rank5_tensor(holdout):
    # The solver centres each xyz coordinate (base class), which adds the rank-one term
    # 1 o 1 o mu: the tensor it factorizes has rank 6, and rank 5 provably cannot fit it.
    X = _cp_tensor((60, 15, 3), 5)
    g = torch.Generator().manual_seed(1)
    missing = torch.rand(X.shape, generator=g) < 0.3
    Xm = X.clone()
    Xm[missing] = float("nan")
    params = {"max_rank": 6, "holdout": None} if holdout is False else {"max_rank": 12}
    solver = get_solver("cp", tol=1e-9, max_iter=3000, **params)
    out = solver.fit_transform(Xm)
    err = float((out - X).norm() / X.norm())
    assert err < 1e-3, (err, solver.rank_, solver.n_iter_)
    if holdout:          # the rank chosen on held-out observed entries is the true one
        assert solver.rank_ == 6


def test_observed_entries_unchanged_and_device_dtype_follow():
    X = _cp_tensor((40, 10, 3), 3).to(torch.float32)
    Xm = X.clone()
    Xm[10:20, 2:4] = float("nan")
    for name in ("cp", "smooth_cp", "sparse_cp"):
        out = get_solver(name, max_iter=50).fit_transform(Xm)
        assert out.dtype == torch.float32 and torch.isfinite(out).all()
        seen = torch.isfinite(Xm)
        assert torch.equal(out[seen], Xm[seen])


def test_holdout_copies_the_gap_pattern_inside_observed_data():
    Omega = torch.ones(100, 12, 3, dtype=torch.bool)
    Omega[40:60, :4] = False
    V = shifted_gap_holdout(Omega, torch.Generator().manual_seed(0))
    assert V is not None and not bool((V & ~Omega).any())
    per_marker = V[:, :, 0].sum(dim=0)
    assert set(per_marker[:4].tolist()) == {20} and int(per_marker[4:].sum()) == 0


def test_holdout_never_takes_more_than_half_of_a_markers_samples():
    # a gap over half the recording: the shifted copy would leave those markers unobserved
    Omega = torch.ones(200, 12, 3, dtype=torch.bool)
    Omega[90:190, :4] = False
    V = shifted_gap_holdout(Omega, torch.Generator().manual_seed(0))
    assert V is not None and not bool((V & ~Omega).any())
    seen = Omega[:, :, 0].sum(dim=0)
    assert bool((V[:, :, 0].sum(dim=0) <= 0.5 * seen).all())


def _fit_fixed_rank(name, X, **params):
    return get_solver(name, holdout=None, max_rank=8, max_iter=150, **params).fit(X)


def _noisy_low_rank():
    X = _cp_tensor((100, 12, 3), 6, seed=3)
    g = torch.Generator().manual_seed(4)
    X = X + 0.05 * X.std() * torch.randn(X.shape, generator=g, dtype=X.dtype)
    X[40:60, :5] = float("nan")
    return X


@pytest.mark.slow                    # benchmark-sized: two fits to convergence
def test_smooth_prior_gives_smoother_time_factors():
    X = _noisy_low_rank()
    roughness = {}
    for name in ("cp", "smooth_cp"):
        A1 = _fit_fixed_rank(name, X).decomposition_.factors[0]
        roughness[name] = float((torch.diff(A1, dim=0) ** 2).sum() / A1.shape[1])
    assert roughness["smooth_cp"] < 0.8 * roughness["cp"], roughness


def test_sparse_prior_gives_sparser_marker_factors():
    X = _noisy_low_rank()
    zeros, ratio = {}, {}
    for name, params in (("cp", {}), ("sparse_cp", {"alpha": 0.1})):
        A2 = _fit_fixed_rank(name, X, **params).decomposition_.factors[1]
        zeros[name] = int((A2.abs() < 1e-12).sum())
        ratio[name] = float((A2.abs().sum(0) / A2.norm(dim=0)).mean())   # l1/l2 per column
    assert zeros["sparse_cp"] > zeros["cp"] and ratio["sparse_cp"] < ratio["cp"], (zeros, ratio)


@pytest.mark.parametrize("name", ["cp", "smooth_cp", "sparse_cp"])
def test_real_recording_beats_linear_interpolation(name, recording):
    truth = _load(recording("cmu_02_01.c3d"))
    T, J, _ = truth.shape
    mask = gaps.shared_window(T, J, n_markers=10, gap_length=50, seed=0)
    X = truth.copy()
    X[mask] = np.nan
    out = get_solver(name).fit_transform(torch.from_numpy(X)).numpy()
    lin = get_solver("linear").fit_transform(torch.from_numpy(X)).numpy()
    err, err_lin = metrics.rmse_missing(out, truth, mask), metrics.rmse_missing(lin, truth, mask)
    assert err < 0.3 * err_lin, (err, err_lin)
    assert np.array_equal(out[~mask], truth[~mask])
