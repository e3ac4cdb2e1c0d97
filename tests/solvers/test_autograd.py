"""grad_tucker / grad_cp: the loss is differentiable as written (gradcheck), the fitted model is a plain
nn.Module a user can train further, low-rank data are recovered, observed entries are kept."""
from __future__ import annotations

import copy

import pytest
import torch

from torchfill import ops
from torchfill.solvers import available, get_solver
from torchfill.solvers.autograd import cp_loss, tucker_loss
from torchfill.solvers.holdout import run_holdout
from torchfill.solvers.factorized import CPTensor, TuckerTensor


def tucker_data(T=60, J=10, rank=(3, 3, 2), missing=0.3, seed=0):
    """Exact Tucker tensor (offset added, as marker data have one) and a (T, J) missing-sample mask."""
    g = torch.Generator().manual_seed(seed)
    G = torch.randn(*rank, generator=g, dtype=torch.float64)
    A = [torch.linalg.qr(torch.randn(n, r, generator=g, dtype=torch.float64)).Q
         for n, r in zip((T, J, 3), rank)]
    X = ops.tucker_to_tensor(G, A) * 100.0 + 50.0
    return X, torch.rand(T, J, generator=g) < missing


def cp_data(T=60, J=10, R=3, missing=0.3, seed=0):
    g = torch.Generator().manual_seed(seed)
    A = [torch.randn(n, R, generator=g, dtype=torch.float64) for n in (T, J, 3)]
    X = ops.cp_to_tensor(torch.ones(R, dtype=torch.float64), A) * 10.0 + 5.0
    return X, torch.rand(T, J, generator=g) < missing


def missing_relerr(F, X, mask):
    m = mask[..., None].expand_as(X)
    return float((F - X)[m].norm() / X[m].norm())


def test_registered():
    assert {"grad_tucker", "grad_cp"} <= set(available())


# -- the loss ----------------------------------------------------------------------------------
@pytest.mark.parametrize("order", [1, 2])
def test_gradcheck_tucker_loss(order):
    g = torch.Generator().manual_seed(1)
    shape, rank = (7, 4, 3), (3, 2, 2)
    M = torch.randn(*shape, generator=g, dtype=torch.float64)
    Omega = torch.rand(*shape, generator=g) < 0.7
    M = torch.where(Omega, M, torch.zeros_like(M))
    G = torch.randn(*rank, generator=g, dtype=torch.float64, requires_grad=True)
    A = [torch.randn(n, r, generator=g, dtype=torch.float64, requires_grad=True)
         for n, r in zip(shape, rank)]
    kw = dict(lam_tnn=0.1, lam_smooth=0.5, lam_l1=0.05, smooth_order=order)
    assert torch.autograd.gradcheck(
        lambda G, A1, A2, A3: tucker_loss(G, [A1, A2, A3], M, Omega, **kw), (G, *A))


def test_gradcheck_cp_loss():
    g = torch.Generator().manual_seed(2)
    shape, R = (6, 5, 3), 2
    M = torch.randn(*shape, generator=g, dtype=torch.float64)
    Omega = torch.rand(*shape, generator=g) < 0.7
    w = torch.rand(R, generator=g, dtype=torch.float64).add(0.5).requires_grad_()
    A = [torch.randn(n, R, generator=g, dtype=torch.float64, requires_grad=True) for n in shape]
    kw = dict(lam_tnn=0.1, lam_smooth=0.5, lam_l1=0.05, smooth_order=2)
    assert torch.autograd.gradcheck(
        lambda w, A1, A2, A3: cp_loss(w, [A1, A2, A3], M, Omega, **kw), (w, *A))


def test_loss_terms_are_what_the_docstring_says():
    X, _ = tucker_data(T=20, J=5)
    Omega = torch.rand(X.shape, generator=torch.Generator().manual_seed(3)) < 0.8
    G, A = ops.multi_mode_dot(X, [torch.eye(n, dtype=X.dtype) for n in X.shape]), \
        [torch.eye(n, dtype=X.dtype) for n in X.shape]
    M = torch.where(Omega, X + 1.0, torch.zeros_like(X))
    n = float(Omega.sum())
    assert torch.allclose(tucker_loss(G, A, M, Omega), torch.tensor(0.5, dtype=X.dtype))
    s = 2.0
    tnn = torch.linalg.svdvals(ops.unfold(X, 0)).sum()
    assert torch.allclose(tucker_loss(G, A, M, Omega, lam_tnn=0.3, scale=s),
                          (0.5 * n + 0.3 * s * tnn) / n)
    l1 = sum(a.abs().sum() for a in A)
    assert torch.allclose(tucker_loss(G, A, M, Omega, lam_l1=0.2, scale=s), (0.5 * n + 0.2 * s * l1) / n)
    d1 = X[1:] - X[:-1]
    assert torch.allclose(tucker_loss(G, A, M, Omega, lam_smooth=2.0),
                          (0.5 * n + (d1 ** 2).sum()) / n)


# -- the fitted model is a plain nn.Module ------------------------------------------------------
def test_fitted_model_in_a_user_training_loop():
    X, mask = tucker_data()
    solver = get_solver("grad_tucker", rank=(4, 4, 3), optimizer="lbfgs", max_iter=30).fit(X, mask)
    model = solver.decomposition_
    assert type(model) is TuckerTensor
    params = list(model.parameters())
    assert len(params) == 4 and all(isinstance(p, torch.nn.Parameter) and p.requires_grad for p in params)
    # state_dict round trip into a fresh model built from shapes only
    fresh = TuckerTensor(torch.zeros(model.rank, dtype=torch.float64),
                         [torch.zeros_like(A) for A in model.factors], learn=True)
    fresh.load_state_dict(model.state_dict())
    assert torch.equal(fresh(), model())
    # .to(dtype)
    m32 = copy.deepcopy(model).to(torch.float32)
    assert m32().dtype == torch.float32 and all(p.dtype == torch.float32 for p in m32.parameters())
    assert torch.allclose(m32().double(), model(), rtol=1e-4, atol=1e-4)
    # a user's own loop: their own loss (here: pull the model toward zero) goes down with SGD
    opt = torch.optim.SGD(m32.parameters(), lr=1e-3)
    losses = []
    for _ in range(5):
        opt.zero_grad()
        loss = m32().pow(2).mean()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < losses[0]


def test_cp_model_is_a_plain_module():
    X, mask = cp_data()
    solver = get_solver("grad_cp", rank=4, optimizer="lbfgs", max_iter=20).fit(X, mask)
    model = solver.decomposition_
    assert type(model) is CPTensor and len(list(model.parameters())) == 4
    fresh = CPTensor(torch.zeros(4, dtype=torch.float64), [torch.zeros_like(A) for A in model.factors],
                     learn=True)
    fresh.load_state_dict(model.state_dict())
    assert torch.equal(fresh(), model())


def test_orthogonal_parametrization_is_removed_after_fit():
    X, mask = tucker_data(T=30, J=6)
    model = get_solver("grad_tucker", rank=(4, 4, 3), ortho="param", optimizer="lbfgs",
                       max_iter=10).fit(X, mask).decomposition_
    assert not hasattr(model, "parametrizations")
    assert set(model.state_dict()) == {"core_tensor", "factor_0", "factor_1", "factor_2"}
    for A in model.factors:
        assert torch.allclose(A.T @ A, torch.eye(A.shape[1], dtype=A.dtype), atol=1e-8)


# -- recovery and observed entries --------------------------------------------------------------
# Centring each coordinate on its observed mean (the base class) adds a rank-one term, so the
# centred tensor has multilinear rank (R1+1, R2+1, min(R3+1, 3)), and a CP rank R+1.
# The bounds below leave a margin over what was measured, and fail on a start that is not refined
# (the HOSVD of the interpolated data, checked below). Both optimizers take long: marked slow.
@pytest.mark.slow                    # both optimizers: 25 s and more on two cores
@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_tucker_recovers_low_rank_tensor(optimizer):
    X, mask = tucker_data()
    kw = {"max_iter": 600} if optimizer == "lbfgs" else {"max_iter": 1000}
    solver = get_solver("grad_tucker", rank=(4, 4, 3), optimizer=optimizer, **kw)
    F = solver.fit_transform(X, mask)
    assert missing_relerr(F, X, mask) < (1e-3 if optimizer == "lbfgs" else 1e-2)   # measured 7e-4, 4e-3
    start = get_solver("grad_tucker", rank=(4, 4, 3), max_iter=1).fit_transform(X, mask)
    assert missing_relerr(start, X, mask) > 1e-2          # the refinement did the work


def test_cp_recovers_low_rank_tensor():
    X, mask = cp_data()
    F = get_solver("grad_cp", rank=4, optimizer="lbfgs", max_iter=300).fit_transform(X, mask)
    assert missing_relerr(F, X, mask) < 1e-2                       # measured 7.7e-4 (2.5e-2 at 150)


@pytest.mark.parametrize("name", ["grad_tucker", "grad_cp"])
def test_observed_entries_unchanged(name):
    X, mask = tucker_data(T=40, J=8)
    Xn = X.clone()
    Xn[mask] = float("nan")
    F = get_solver(name, max_iter=20).fit_transform(Xn)
    assert torch.equal(F[~mask], X[~mask])
    assert bool(torch.isfinite(F).all())


def test_dtype_follows_input():
    X, mask = tucker_data(T=40, J=8)
    X = X.to(torch.float32)
    X[mask] = float("nan")
    solver = get_solver("grad_tucker", rank=(4, 4, 3), max_iter=20)
    F = solver.fit_transform(X)
    assert F.dtype == torch.float32 and solver.decomposition_.core.dtype == torch.float32


def test_holdout_is_observed_only_and_gap_shaped():
    X, mask = tucker_data(T=200, J=10, missing=0.01)
    Omega = (~mask)[..., None].expand_as(X)
    held = run_holdout(Omega, 0.05, 20, torch.Generator().manual_seed(0))
    assert bool(held.any()) and not bool((held & ~Omega).any())
    solver = get_solver("grad_tucker", rank=(4, 4, 3), holdout="runs", holdout_share=0.05, max_iter=30).fit(X, mask)
    assert "holdout_rmse" in solver.history_[-1]
    assert not bool((solver.fit_mask_ & solver.holdout_mask_).any())


def test_step_is_one_optimizer_step_and_history_grows():
    X, mask = tucker_data(T=30, J=6)
    solver = get_solver("grad_tucker", rank=(4, 4, 3))
    solver.initialize(X, mask)
    before = [p.detach().clone() for p in solver.decomposition_.parameters()]
    info = solver.step_and_record()
    assert solver.n_iter_ == 1 and len(solver.history_) == 1 and "loss" in info
    assert any(not torch.equal(b, p) for b, p in zip(before, solver.decomposition_.parameters()))


def test_bad_hyperparameters():
    with pytest.raises(ValueError, match="optimizer"):
        get_solver("grad_tucker", optimizer="sgd")
    with pytest.raises(ValueError, match="rank"):
        get_solver("grad_tucker", rank=(2, 2)).fit(tucker_data(T=20, J=5)[0])


@pytest.mark.skipif("tucker" not in available(), reason="closed-form tucker not registered")
def test_closed_form_start_is_the_closed_form_fit(monkeypatch):
    import torchfill.solvers.autograd as ag
    made = []

    def spy(name, **kw):
        made.append(get_solver(name, **kw))
        return made[-1]

    monkeypatch.setattr(ag, "get_solver", spy)
    X, mask = tucker_data(T=40, J=8)
    solver = get_solver("grad_tucker", init="closed_form", init_params={"max_iter": 30}).initialize(X, mask)
    closed = made[0]
    assert closed.name == "tucker" and closed.n_iter_ > 0
    ref = ag._find_model(closed, TuckerTensor)
    assert torch.allclose(solver.decomposition_(), ref(), atol=1e-8)       # same tensor, normalized units
    for A in solver.decomposition_.factors:                                 # re-orthonormalized
        assert torch.allclose(A.T @ A, torch.eye(A.shape[1], dtype=A.dtype), atol=1e-8)
