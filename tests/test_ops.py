"""Building blocks: unfoldings, mode products, proximal operators, interpolation."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchfill
from torchfill import ops


def rand(*shape, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(*shape, generator=g, dtype=dtype)


# -- unfold / fold -------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", [0, 1, 2])
def test_unfold_fold_round_trip(mode):
    X = rand(7, 5, 3)
    M = ops.unfold(X, mode)
    assert M.shape == (X.shape[mode], X.numel() // X.shape[mode])
    assert torch.equal(ops.fold(M, mode, X.shape), X)


def test_temporal_unfolding_is_T_by_3J_x1_y1_z1_x2():
    T, J = 4, 3
    X = torch.arange(T * J * 3, dtype=torch.float64).reshape(T, J, 3)
    M = ops.unfold(X, 0)
    assert M.shape == (T, 3 * J)
    for t in range(T):
        for j in range(J):
            for c in range(3):
                assert M[t, 3 * j + c] == X[t, j, c]         # columns x1 y1 z1 x2 y2 z2 ...
    # the DESIGN.md warning: a column-major reshape scrambles markers and coordinates
    assert not np.array_equal(M.numpy(), X.numpy().reshape(T, 3 * J, order="F"))


@pytest.mark.parametrize("mode", [0, 1, 2])
def test_mode_dot_matches_einsum(mode):
    X = rand(6, 5, 3, seed=1)
    A = rand(4, X.shape[mode], seed=2)
    Y = ops.mode_dot(X, A, mode)
    want = torch.einsum({0: "tjc,it->ijc", 1: "tjc,ij->tic", 2: "tjc,ic->tji"}[mode], X, A)
    torch.testing.assert_close(Y, want)
    # mode-n product = A @ unfolding, folded back
    torch.testing.assert_close(ops.unfold(Y, mode), A @ ops.unfold(X, mode))


def test_tucker_and_cp_to_tensor_match_einsum():
    G = rand(3, 2, 2, seed=3)
    A = [rand(8, 3, seed=4), rand(5, 2, seed=5), rand(3, 2, seed=6)]
    torch.testing.assert_close(ops.tucker_to_tensor(G, A),
                               torch.einsum("abc,ia,jb,kc->ijk", G, *A))
    w = rand(4, seed=7)
    F = [rand(8, 4, seed=8), rand(5, 4, seed=9), rand(3, 4, seed=10)]
    torch.testing.assert_close(ops.cp_to_tensor(w, F), torch.einsum("r,ir,jr,kr->ijk", w, *F))


def test_multi_mode_dot_skip_and_transpose():
    X = rand(6, 5, 3, seed=11)
    A = [rand(6, 6, seed=12), rand(5, 5, seed=13), rand(3, 3, seed=14)]
    got = ops.multi_mode_dot(X, A, skip=1, transpose=True)
    torch.testing.assert_close(got, torch.einsum("tjc,ti,ck->ijk", X, A[0], A[2]))


def test_ops_follow_tensorly_conventions():
    """The direct torch contractions agree with TensorLy's (row-major unfolding, mode order)."""
    import tensorly as tl
    from tensorly import tenalg
    X = rand(7, 5, 3, seed=20)
    A = [rand(4, 7, seed=21), rand(2, 5, seed=22), rand(3, 3, seed=23)]
    with tl.backend_context("pytorch"):
        for n in range(3):
            assert torch.equal(ops.unfold(X, n), tl.unfold(X, n))
            torch.testing.assert_close(ops.mode_dot(X, A[n], n), tenalg.mode_dot(X, A[n], n))
        torch.testing.assert_close(ops.multi_mode_dot(X, A), tenalg.multi_mode_dot(X, A))
        torch.testing.assert_close(ops.multi_mode_dot(X, [a.T for a in A], skip=1, transpose=True),
                                   tenalg.multi_mode_dot(X, [a.T for a in A], skip=1, transpose=True))


def test_khatri_rao_and_mttkrp_match_tensorly():
    import tensorly as tl
    from tensorly import tenalg
    X = rand(6, 5, 3, seed=24)
    A = [rand(6, 4, seed=25), rand(5, 4, seed=26), rand(3, 4, seed=27)]
    with tl.backend_context("pytorch"):
        torch.testing.assert_close(ops.khatri_rao(A[1], A[2]), tenalg.khatri_rao([A[1], A[2]]))
        for n in range(3):
            torch.testing.assert_close(ops.mttkrp(X, A, n), tenalg.unfolding_dot_khatri_rao(X, (torch.ones(4, dtype=X.dtype), A), n))


def test_hosvd_reconstructs_a_tensor_of_that_rank():
    G, A = rand(3, 2, 2, seed=28), [rand(9, 3, seed=29), rand(6, 2, seed=30), rand(3, 2, seed=31)]
    X = ops.tucker_to_tensor(G, A)
    core, factors = ops.hosvd(X, (3, 2, 2))
    torch.testing.assert_close(ops.tucker_to_tensor(core, factors), X)
    assert [f.shape for f in factors] == [(9, 3), (6, 2), (3, 2)]


# -- proximal operators --------------------------------------------------------------------------
def test_soft_threshold():
    x = torch.tensor([-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 3.0], dtype=torch.float64)
    torch.testing.assert_close(ops.soft_threshold(x, 1.0),
                               torch.tensor([-2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0], dtype=torch.float64))
    y = rand(50, seed=15)
    # the prox of tau*|.|_1 minimizes 0.5 (z - y)^2 + tau |z| elementwise
    z = ops.soft_threshold(y, 0.3)
    for dz in (-1e-3, 1e-3):
        obj = lambda v: 0.5 * (v - y) ** 2 + 0.3 * v.abs()  # noqa: E731
        assert bool((obj(z) <= obj(z + dz) + 1e-12).all())
    assert ops.soft_threshold(y.float(), 0.3).dtype == torch.float32


@pytest.mark.parametrize("tau", [0.0, 0.5, 2.0, 1e6])
def test_svt_against_explicit_svd(tau):
    M = rand(30, 12, seed=16)
    got, r = ops.svt(M, tau)
    U, S, Vh = np.linalg.svd(M.numpy(), full_matrices=False)
    S = np.maximum(S - tau, 0.0)
    np.testing.assert_allclose(got.numpy(), (U * S) @ Vh, atol=1e-10)
    assert r == int((S > 0).sum())
    assert got.shape == M.shape


@pytest.mark.parametrize("shape", [(300, 30), (30, 300)])
def test_svt_gram_matches_svd(shape):
    g = torch.Generator().manual_seed(1)
    M = torch.randn(shape[0], 12, generator=g, dtype=torch.float64) @ torch.randn(12, shape[1], generator=g,
                                                                                dtype=torch.float64)
    S = torch.linalg.svdvals(M)
    tau = float(S[4] + S[5]) / 2
    (got, r), (want, r_full) = ops.svt(M, tau, "gram"), ops.svt(M, tau, "full")
    assert r == r_full == 5 and torch.allclose(got, want, atol=1e-9)


@pytest.mark.parametrize("kept", [5, 20])      # the (Z V_r) V_r^T product and the Z (V V^T) one
def test_svt_gram_full_rank_matches_svd(kept):
    M = torch.randn(300, 30, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    S = torch.linalg.svdvals(M)
    tau = float(S[kept - 1] + S[kept]) / 2
    (got, r), (want, _) = ops.svt(M, tau, "gram"), ops.svt(M, tau, "full")
    assert r == kept and torch.allclose(got, want, atol=1e-9)


def test_energy_rank_and_difference_operators():
    M = torch.diag(torch.tensor([3.0, 2.0, 1.0], dtype=torch.float64))     # energies 9, 4, 1
    assert [ops.energy_rank(M, e) for e in (0.5, 0.9, 0.99)] == [1, 2, 3]
    a, T = rand(11, seed=32), 11
    D = torch.diff(torch.eye(T, dtype=torch.float64), dim=0)
    torch.testing.assert_close(ops.difference(a, 1), D @ a)
    torch.testing.assert_close(ops.difference_gram(a), D.T @ D @ a)
    y = rand(T - 2, seed=33)
    D2 = torch.diff(torch.eye(T, dtype=torch.float64), n=2, dim=0)
    torch.testing.assert_close(ops.difference_adjoint(y, 2, T), D2.T @ y)


def test_runs_lists_every_run_per_column():
    mask = torch.tensor([[1, 0], [1, 1], [0, 1], [1, 0]], dtype=torch.bool)
    assert ops.runs(mask) == [(0, 0, 2), (0, 3, 4), (1, 1, 3)]


def test_svt_is_prox_of_nuclear_norm():
    """D_tau(Y) minimizes 0.5||X - Y||_F^2 + tau ||X||_*: no random perturbation does better."""
    Y, tau = rand(10, 8, seed=17), 1.0
    X, _ = ops.svt(Y, tau)

    def obj(Z):
        return 0.5 * ((Z - Y) ** 2).sum() + tau * torch.linalg.svdvals(Z).sum()

    for seed in range(10):
        assert obj(X) <= obj(X + 1e-3 * rand(10, 8, seed=100 + seed)) + 1e-12


@pytest.mark.parametrize("keep", [1, 3])
def test_partial_svt_keeps_leading_singular_values(keep):
    """``keep`` leading singular values untouched, the rest shrunk (PSTNN's shrinkage), real and
    complex input."""
    M = rand(20, 9, seed=18)
    for A in (M, torch.complex(M, rand(20, 9, seed=19))):
        got, _ = ops.svt(A, 0.5, keep=keep)
        S = torch.linalg.svdvals(A)
        want = torch.cat([S[:keep], torch.clamp(S[keep:] - 0.5, min=0.0)])
        torch.testing.assert_close(torch.linalg.svdvals(got)[:len(want)], want)


def test_orthonormalize():
    Q = ops.orthonormalize(rand(20, 4, seed=18))
    torch.testing.assert_close(Q.T @ Q, torch.eye(4, dtype=torch.float64))


# -- interp_linear -------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_interp_linear_matches_np_interp_with_held_ends(seed, dtype):
    rng = np.random.default_rng(seed)
    T, N = 60, 9
    M = rng.normal(size=(T, N))
    W = rng.random((T, N)) < 0.4
    W[:, 0] = False
    W[[3, 50], 0] = True                                   # leading and trailing gaps held
    W[:, 1] = False
    W[17, 1] = True                                        # a single observation: constant
    W[:, 2] = True                                         # fully observed: unchanged
    Mt = torch.tensor(np.where(W, M, 123.0), dtype=dtype)   # values at gaps must be ignored
    got = ops.interp_linear(Mt, torch.from_numpy(W))
    assert got.dtype == dtype and got.shape == (T, N)
    t = np.arange(T)
    for n in range(N):
        obs = W[:, n]
        want = np.interp(t, t[obs], M[obs, n]) if obs.any() else np.zeros(T)  # np.interp holds ends
        tol = 1e-12 if dtype == torch.float64 else 1e-5
        np.testing.assert_allclose(got[:, n].double().numpy(), want, atol=tol, rtol=tol)
    assert bool((got[W] == Mt[torch.from_numpy(W)]).all())   # observed bit-for-bit
    alone = torch.cat([ops.interp_linear(Mt[:, n:n + 1], torch.from_numpy(W[:, n:n + 1]))
                       for n in range(N)], 1)                # each column on its own: same bits
    assert torch.equal(got, alone)


def test_interp_linear_unobserved_column_is_zero_and_no_nan():
    M = torch.full((10, 2), float("nan"), dtype=torch.float64)
    W = torch.zeros(10, 2, dtype=torch.bool)
    M[::3, 1] = torch.arange(0.0, 10.0, 3.0)
    W[::3, 1] = True
    out = ops.interp_linear(M, W)                          # NaN at gaps is ignored
    assert torch.equal(out[:, 0], torch.zeros(10, dtype=torch.float64))
    torch.testing.assert_close(out[:, 1], torch.tensor([0, 1, 2, 3, 4, 5, 6, 7, 8, 9.0],
                                                       dtype=torch.float64))
