"""Matrix-completion family: svt, trnn, trnn_d2 (and their building blocks)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.solvers import get_solver
from torchfill.solvers.matrix import (BandedCholesky, d2_system_bands, difference,
                                      difference_adjoint, difference_gram_bands, energy_rank, svt)


def _low_rank(T=200, J=20, rank=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(T, rank, generator=g, dtype=torch.float64)
    B = torch.randn(rank, 3 * J, generator=g, dtype=torch.float64)
    return (A @ B).reshape(T, J, 3), g


def _dense_d2_system(T):
    I = torch.eye(T, dtype=torch.float64)
    D1, D2 = torch.diff(I, n=1, dim=0), torch.diff(I, n=2, dim=0)
    return 2 * I + D1.T @ D1 + D2.T @ D2


# -- building blocks ------------------------------------------------------------------------------
@pytest.mark.parametrize("T,block", [(2, None), (3, None), (17, None), (50, 8), (53, 7), (301, None)])
def test_banded_solve_equals_dense_solve(T, block):
    K = _dense_d2_system(T)
    bands = d2_system_bands(T)
    for d in range(3):                                   # the bands are those of the dense matrix
        torch.testing.assert_close(bands[d, d:], torch.diagonal(K, -d))
    B = torch.randn(T, 9, generator=torch.Generator().manual_seed(T), dtype=torch.float64)
    x = BandedCholesky(bands, block).solve(B)
    torch.testing.assert_close(x, torch.linalg.solve(K, B), rtol=1e-10, atol=1e-12)


def test_banded_cholesky_factor_is_the_factor():
    T = 40
    chol = BandedCholesky(d2_system_bands(T))
    L = torch.zeros(T, T, dtype=torch.float64)
    for d in range(3):
        idx = torch.arange(d, T)
        L[idx, idx - d] = chol.L_bands[d, d:]
    torch.testing.assert_close(L, torch.linalg.cholesky(_dense_d2_system(T)))


@pytest.mark.parametrize("order", [1, 2, 3])
def test_difference_adjoint_and_gram(order):
    T = 23
    g = torch.Generator().manual_seed(order)
    X = torch.randn(T, 4, generator=g, dtype=torch.float64)
    Y = torch.randn(T - order, 4, generator=g, dtype=torch.float64)
    lhs = (difference(X, order) * Y).sum()
    rhs = (X * difference_adjoint(Y, order, T)).sum()
    torch.testing.assert_close(lhs, rhs)
    D = torch.diff(torch.eye(T, dtype=torch.float64), n=order, dim=0)
    bands = difference_gram_bands(T, order)
    for d in range(order + 1):
        torch.testing.assert_close(bands[d, d:], torch.diagonal(D.T @ D, -d))


@pytest.mark.parametrize("shape", [(300, 12), (12, 300)])
def test_gram_svt_matches_full_svd(shape):
    M = torch.randn(*shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    s1 = torch.linalg.matrix_norm(M, ord=2)
    for tau in (0.1 * s1, 0.5 * s1):
        A, ra = svt(M, float(tau), "gram")
        B, rb = svt(M, float(tau), "full")
        assert ra == rb
        torch.testing.assert_close(A, B, rtol=1e-9, atol=1e-9)


def test_energy_rank_counts_the_spectrum():
    g = torch.Generator().manual_seed(2)
    U = torch.linalg.qr(torch.randn(50, 6, dtype=torch.float64, generator=g)).Q
    V = torch.linalg.qr(torch.randn(8, 6, dtype=torch.float64, generator=g)).Q
    s = torch.tensor([10.0, 3.0, 1.0, 0.3, 0.1, 0.01], dtype=torch.float64)
    M = U * s @ V.T
    share = torch.cumsum(s ** 2, 0) / (s ** 2).sum()
    for energy in (0.5, 0.9, 0.99, 0.9999):
        r = energy_rank(M, energy)
        assert share[r - 1] >= energy and (r == 1 or share[r - 2] < energy)


# -- solvers --------------------------------------------------------------------------------------
@pytest.mark.parametrize("method,params", [("svt", {}), ("trnn", {"rank": 5})])
def test_exact_recovery_of_a_rank5_matrix(method, params):
    X, g = _low_rank()
    missing = torch.rand(X.shape, generator=g) < 0.4
    Xn = X.clone()
    Xn[missing] = float("nan")
    out = get_solver(method, tol=1e-6, **params).fit_transform(Xn)
    err = torch.linalg.norm(out - X) / torch.linalg.norm(X)
    assert err < 1e-3, f"{method}: relative error {float(err):.2e}"


@pytest.mark.parametrize("method", ["svt", "trnn", "trnn_d2"])
def test_observed_entries_unchanged_and_units_invariant(method):
    X, g = _low_rank(T=120, J=8, rank=4)
    X = X + 0.05 * torch.randn(X.shape, generator=g, dtype=torch.float64)  # not exactly low rank
    mask = torch.from_numpy(gaps.continuous_runs(120, 8, n_markers=3, gap_length=20, seed=0))
    Xn = X.clone()
    Xn[mask] = float("nan")
    solver = get_solver(method, max_iter=60)
    solver.initialize(Xn)
    est = solver.forward()                                   # the iterate reported, X_0 included
    assert torch.equal(est[~mask], Xn[~mask]) or torch.allclose(est[~mask], Xn[~mask], atol=1e-9)
    for _ in range(5):
        solver.step_and_record()
        assert torch.allclose(solver.forward()[~mask], Xn[~mask], atol=1e-9)
    out = get_solver(method, max_iter=60).fit_transform(Xn)
    assert torch.equal(out[~mask], Xn[~mask])                # bit-for-bit through transform()
    assert torch.isfinite(out).all()
    scaled = get_solver(method, max_iter=60).fit_transform(1000.0 * Xn + 250.0)
    torch.testing.assert_close(scaled, 1000.0 * out + 250.0, rtol=1e-6, atol=1e-6)


def _load(path) -> np.ndarray:
    return torchfill.read(path).points   # the reader drops HDM05's `*` copies


def test_trnn_d2_beats_linear_on_real_continuous_gaps(recording):
    """Imamura & Okuda's claim on a recording of ours: 40-frame runs on 10 markers (Fig. 1b)."""
    P = _load(recording("cmu_02_01.c3d"))
    T, J, _ = P.shape
    wins = 0
    for seed in (0, 1):
        mask = gaps.continuous_runs(T, J, n_markers=10, gap_length=40, seed=seed)
        X = P.copy()
        X[mask] = np.nan
        out = torchfill.fill(X, method="trnn_d2")
        lin = torchfill.fill(X, method="linear")
        assert np.array_equal(out[~mask], P[~mask])
        e, e_lin = metrics.rmse_missing(out, P, mask), metrics.rmse_missing(lin, P, mask)
        assert e < e_lin, f"seed {seed}: trnn_d2 {e:.2f} mm vs linear {e_lin:.2f} mm"
        wins += e < 0.8 * e_lin
    assert wins >= 1
