"""Tensor algebra: unfoldings, mode products, Tucker and CP reconstructions, Khatri-Rao, MTTKRP.

TensorLy's conventions throughout (row-major unfolding). Where TensorLy's torch backend is as fast
or faster it does the work (``multi_mode_dot``, ``cp_to_tensor``), under
``tl.backend_context("pytorch")``, never ``tl.set_backend``; where it is slower our own torch
contraction stays, each saying by how much (timed per call at a recording's
sizes, 1000 x 41 x 3, Tucker rank (40, 24, 3), CP rank 40, one thread, median of runs on a loaded
2-core machine). Autograd flows through all of them.
"""
from __future__ import annotations

from collections.abc import Sequence

import torch

Tensor = torch.Tensor

def _tensorly():
    """TensorLy with its torch backend selected for this thread, as a context manager."""
    import tensorly as tl
    return tl, tl.backend_context("pytorch")


def unfold(X: Tensor, mode: int) -> Tensor:
    """Mode-``mode`` unfolding: shape ``(X.shape[mode], prod(other dims))``.

    TensorLy's row-major column order (not Kolda & Bader's column-major one): for a recording
    ``(T, J, 3)`` the temporal unfolding (mode 0) is ``T x 3J`` with columns ``x1 y1 z1 x2 ...``.
    Ours: ``tl.unfold`` is the same movedim + reshape plus the backend switch, 1.15x our time.
    """
    return torch.movedim(X, mode, 0).reshape(X.shape[mode], -1)


def fold(M: Tensor, mode: int, shape: Sequence[int]) -> Tensor:
    """Inverse of :func:`unfold`. Ours: ``tl.fold`` took 7x our time (the backend switch costs
    more than this reshape)."""
    shape = list(shape)
    full = [shape[mode]] + shape[:mode] + shape[mode + 1:]
    return torch.movedim(M.reshape(full), 0, mode)


def mode_dot(X: Tensor, A: Tensor, mode: int) -> Tensor:
    """n-mode product ``X x_n A`` (``A`` has shape ``(I_new, X.shape[mode])``). Ours:
    ``tl.tenalg.mode_dot`` took 1.07x our time (it unfolds, multiplies and folds)."""
    return torch.movedim(torch.tensordot(X, A, dims=([mode], [1])), -1, mode)


def multi_mode_dot(X: Tensor, factors: Sequence[Tensor], *, skip: int | None = None,
                   transpose: bool = False) -> Tensor:
    """``X x_1 A1 x_2 A2 ...`` over all modes but ``skip``, in mode order; ``transpose`` uses
    ``An^T`` (the projection ``X x_n An^T`` of the Tucker core updates). TensorLy's
    ``tl.tenalg.multi_mode_dot`` (0.92x the time of our mode-by-mode loop)."""
    tl, backend = _tensorly()
    with backend:
        return tl.tenalg.multi_mode_dot(X, list(factors), skip=skip, transpose=transpose)


def tucker_to_tensor(G: Tensor, factors: Sequence[Tensor]) -> Tensor:
    """``G x_1 A(1) x_2 A(2) x_3 A(3)``, the long time mode last (the cheapest order). Ours:
    ``tl.tucker_to_tensor`` goes in mode order, the long time mode first: 2.2x our time."""
    for n in reversed(range(len(factors))):
        G = mode_dot(G, factors[n], n)
    return G


def cp_to_tensor(weights: Tensor, factors: Sequence[Tensor]) -> Tensor:
    """``sum_r w_r a_r^(1) o a_r^(2) o ...`` for factors of shape ``(I_n, R)``: TensorLy's
    ``tl.cp_to_tensor`` (one matrix product with a Khatri-Rao product; 0.19x the time of the
    single ``einsum`` we had, which torch ran as a batched outer product)."""
    tl, backend = _tensorly()
    with backend:
        return tl.cp_to_tensor((weights, list(factors)))


def khatri_rao(B: Tensor, C: Tensor) -> Tensor:
    """Column-wise Kronecker product: row ``j * K + d`` is ``B[j] * C[d]`` (shape ``JK x R``).
    Ours: ``tl.tenalg.khatri_rao`` (general n-ary, with checks) took 2.25x our time."""
    return (B[:, None, :] * C[None, :, :]).reshape(-1, B.shape[1])


def mttkrp(X: Tensor, A: Sequence[Tensor], n: int, Z: Tensor | None = None) -> Tensor:
    """``X x_{-n} {a_r}`` for every CP component at once, ``X`` third-order: column ``r`` is ``X``
    contracted with ``a_r(m)`` over every mode ``m != n`` (I_n x R). ``Z = X_(1)^T A(1)`` reshaped
    (J, K, R) may be passed for modes 2 and 3 (it is shared by both)."""
    T, J, K = X.shape
    if n == 0:
        return X.reshape(T, J * K) @ khatri_rao(A[1], A[2])
    if Z is None:
        Z = (X.reshape(T, J * K).T @ A[0]).reshape(J, K, -1)
    if n == 1:
        return (Z * A[2][None]).sum(dim=1)
    return (Z * A[1][:, None]).sum(dim=0)


def hosvd(X: Tensor, rank: Sequence[int]) -> tuple[Tensor, list[Tensor]]:
    """Truncated higher-order SVD: ``A(n)`` = the leading ``R_n`` left singular vectors of
    ``X_(n)``, core ``G = X x_n A(n)^T``."""
    A = [torch.linalg.svd(unfold(X, n), full_matrices=False).U[:, :R].contiguous()
         for n, R in enumerate(rank)]
    return multi_mode_dot(X, A, transpose=True), A


def clamp_tiny(x: Tensor, floor: float = 1e-300) -> Tensor:
    """``x`` clamped to at least ``floor``, or to the dtype's smallest normal number where
    ``floor`` is below that (1e-300 is 0 in float32: a division by it gives inf or NaN)."""
    return x.clamp(min=max(floor, torch.finfo(x.dtype).tiny))
