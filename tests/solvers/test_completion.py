"""HaLRTC, SPC and PSTNN (the CP paper's baselines): exact recovery of synthetic low-rank tensors
with 30 % of the entries missing, observed entries unchanged. The common contract is in
test_contract.py (parametrized over every registered method)."""
from __future__ import annotations

import pytest
import torch

from torchfill.solvers import get_solver
from torchfill.solvers.spc import tv_denoise


def _missing(shape, share=0.3, seed=0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=g, dtype=torch.float64) < share


def cp_tensor(T=80, J=20, K=3, R=3, seed=0) -> torch.Tensor:
    """A rank-R CP tensor with smooth time factors (what SPC's prior expects); the solvers
    centre each xyz axis, which adds one rank-one term, hence rank_max = 6 below."""
    g = torch.Generator().manual_seed(seed)
    t = torch.linspace(0, 1, T, dtype=torch.float64)[:, None]
    A = torch.sin(2 * torch.pi * t * torch.arange(1, R + 1) + torch.rand(R, generator=g,
                                                                           dtype=torch.float64))
    B = torch.randn(J, R, generator=g, dtype=torch.float64)
    C = torch.randn(K, R, generator=g, dtype=torch.float64)
    return torch.einsum("tr,jr,kr->tjk", A, B, C) * 100.0


def tubal_tensor(T=80, J=20, K=3, r=2, seed=0) -> torch.Tensor:
    """Tubal rank r: every Fourier frontal slice (FFT along mode 3) has rank <= r."""
    g = torch.Generator().manual_seed(seed)
    U = torch.randn(T, r, K, generator=g, dtype=torch.float64)
    V = torch.randn(r, J, K, generator=g, dtype=torch.float64)
    Uf, Vf = torch.fft.fft(U, dim=2), torch.fft.fft(V, dim=2)
    return torch.fft.ifft(torch.einsum("trk,rjk->tjk", Uf, Vf), dim=2).real * 100.0


def _recover(method, X, **kw):
    missing = _missing(X.shape)
    solver = get_solver(method, **kw)
    out = solver.fit_transform(X, missing)
    assert torch.equal(out[~missing], X[~missing]), "observed entries changed"
    return float((out - X)[missing].norm() / X[missing].norm())


@pytest.mark.parametrize("method,kw", [
    ("halrtc", {"tol": 1e-7, "max_iter": 2000}),
    ("spc", {"rho": 0.0, "holdout": False, "rank_max": 6, "tol": 1e-10, "max_iter": 3000}),
    ("spc", {"rho": 1e-3, "holdout": False, "rank_max": 6, "tol": 1e-10, "max_iter": 3000}),
])
def test_exact_recovery_of_low_rank_tensor(method, kw):
    assert _recover(method, cp_tensor(), **kw) < 1e-3


@pytest.mark.parametrize("N", [0, 2])
def test_pstnn_exact_recovery_of_low_tubal_rank_tensor(N):
    """Tubal rank 2: recovered by the tubal nuclear norm (N = 0) and by the partial sum that
    leaves the 2 signal singular values of each slice unshrunk (N = 2)."""
    assert _recover("pstnn", tubal_tensor(r=2), N=N, tol=1e-7, max_iter=2000) < 1e-3


def test_tv_denoise_keeps_a_step_and_flattens_noise():
    z = torch.cat([torch.zeros(50), torch.ones(50)]).double()
    noise = 0.05 * torch.randn(100, generator=torch.Generator().manual_seed(0), dtype=z.dtype)
    u = tv_denoise(z + noise, 0.1, 500)
    assert float((u - z).norm()) < float(noise.norm())             # closer to the clean step
    assert float(u[60:].mean() - u[:40].mean()) > 0.7              # the step survives
