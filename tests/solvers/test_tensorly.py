"""Fitted decompositions hand over to TensorLy, and the ops that TensorLy does agree with ours."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import tensorly as tl
import torch
from tensorly.cp_tensor import CPTensor as TLCP
from tensorly.tucker_tensor import TuckerTensor as TLTucker

from torchfill import ops
from torchfill.solvers import available, get_solver
from torchfill.solvers.factorized import CPTensor, TuckerTensor

T, J = 120, 8
_t = np.arange(T)[:, None, None] / 60.0
_B = np.random.default_rng(0).normal(0.0, 60.0, size=(1, J, 3))
GAPPY = 300 + _B * np.sin(2 * np.pi * 0.9 * _t + _B / 60) + _B * _t
GAPPY[20:35, 1] = GAPPY[60:80, 4] = np.nan

FACTORIZED = {"tucker": {"max_iter": 5}, "tucker_tnn": {"max_iter": 5}, "cp": {"max_iter": 5},
              "smooth_cp": {"max_iter": 5}, "sparse_cp": {"max_iter": 5},
              "grad_tucker": {"max_iter": 5, "rank": [3, 3, 3]},
              "grad_cp": {"max_iter": 5, "rank": 3}}


@pytest.mark.parametrize("method", [m for m in FACTORIZED if m in available()])
def test_decomposition_to_tensorly(method):
    solver = get_solver(method, **FACTORIZED[method])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver.fit(torch.from_numpy(GAPPY))
    model = solver.decomposition_
    tlt = model.to_tensorly()
    with tl.backend_context("pytorch"):
        if isinstance(model, TuckerTensor):
            assert isinstance(tlt, TLTucker)
            full = tl.tucker_to_tensor(tlt)
        else:
            assert isinstance(model, CPTensor) and isinstance(tlt, TLCP)
            full = tl.cp_to_tensor(tlt)
    torch.testing.assert_close(full, model().detach())
    assert not full.requires_grad


def test_tensorly_backed_ops_match_a_reference_and_leave_the_backend_alone():
    g = torch.Generator().manual_seed(0)
    X = torch.randn(30, 7, 3, generator=g, dtype=torch.float64)
    A = [torch.randn(n, r, generator=g, dtype=torch.float64) for n, r in ((30, 4), (7, 5), (3, 2))]
    w = torch.randn(4, generator=g, dtype=torch.float64)
    C = [torch.randn(n, 4, generator=g, dtype=torch.float64) for n in (30, 7, 3)]
    before = tl.get_backend()
    ref = np.einsum("z,az,bz,cz->abc", w.numpy(), *[c.numpy() for c in C])
    np.testing.assert_allclose(ops.cp_to_tensor(w, C).numpy(), ref, rtol=1e-12, atol=1e-12)
    ref = np.einsum("abc,ai,bj,ck->ijk", X.numpy(), *[a.numpy() for a in A])
    np.testing.assert_allclose(ops.multi_mode_dot(X, A, transpose=True).numpy(), ref,
                               rtol=1e-12, atol=1e-12)
    ref = np.einsum("abc,ai,ck->ibk", X.numpy(), A[0].numpy(), A[2].numpy())
    np.testing.assert_allclose(ops.multi_mode_dot(X, A, transpose=True, skip=1).numpy(), ref,
                               rtol=1e-12, atol=1e-12)
    assert tl.get_backend() == before                       # never tl.set_backend
    w.requires_grad_(True)
    ops.cp_to_tensor(w, C).sum().backward()                 # autograd flows through TensorLy
    assert w.grad is not None and w.grad.shape == w.shape
