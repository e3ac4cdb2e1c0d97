"""Building blocks shared by the solvers: unfoldings, mode products, proximal operators.

Tensor algebra goes through TensorLy's functional API under a local torch backend
(``tensorly.backend_context``), never a global ``tl.set_backend``.
"""
from __future__ import annotations

from collections.abc import Sequence

import tensorly as tl
import torch
from tensorly import tenalg

Tensor = torch.Tensor


def unfold(X: Tensor, mode: int) -> Tensor:
    """Mode-``mode`` unfolding: shape ``(X.shape[mode], prod(other dims))``.

    TensorLy's row-major column order (not Kolda & Bader's column-major one): for a recording
    ``(T, J, 3)`` the temporal unfolding (mode 0) is ``T x 3J`` with columns ``x1 y1 z1 x2 ...``.
    """
    with tl.backend_context("pytorch"):
        return tl.unfold(X, mode)


def fold(M: Tensor, mode: int, shape: Sequence[int]) -> Tensor:
    """Inverse of :func:`unfold`."""
    with tl.backend_context("pytorch"):
        return tl.fold(M, mode, tuple(shape))


def mode_dot(X: Tensor, A: Tensor, mode: int) -> Tensor:
    """n-mode product ``X x_n A`` (``A`` has shape ``(I_new, X.shape[mode])``)."""
    with tl.backend_context("pytorch"):
        return tenalg.mode_dot(X, A, mode)


def multi_mode_dot(X: Tensor, factors: Sequence[Tensor], *, skip: int | None = None,
                   transpose: bool = False) -> Tensor:
    """``X x_1 A1 x_2 A2 ...`` over all modes but ``skip``; ``transpose`` uses ``An^T``."""
    with tl.backend_context("pytorch"):
        return tenalg.multi_mode_dot(X, list(factors), skip=skip, transpose=transpose)


def tucker_to_tensor(G: Tensor, factors: Sequence[Tensor]) -> Tensor:
    """``G x_1 A1 x_2 A2 x_3 A3``."""
    return multi_mode_dot(G, factors)


def cp_to_tensor(weights: Tensor, factors: Sequence[Tensor]) -> Tensor:
    """``sum_r w_r a_r^(1) o a_r^(2) o a_r^(3)`` for factors of shape ``(I_n, R)``."""
    with tl.backend_context("pytorch"):
        return tl.cp_to_tensor((weights, list(factors)))


def soft_threshold(x: Tensor, tau: float | Tensor) -> Tensor:
    """Proximal operator of ``tau * ||x||_1``: ``sign(x) * max(|x| - tau, 0)``."""
    return torch.sign(x) * torch.clamp(x.abs() - tau, min=0.0)


def svt(M: Tensor, tau: float | Tensor, keep: int = 0) -> tuple[Tensor, int]:
    """Singular value thresholding ``D_tau(M) = U max(S - tau, 0) V^T`` (prox of ``tau ||.||_*``).

    ``keep`` leading singular values are left untouched (partial singular value thresholding,
    the prox of ``tau`` times the partial sum ``sum_{i > keep} sigma_i``). Real or complex ``M``.
    Returns the thresholded matrix and the number of singular values kept.
    """
    U, S, Vh = torch.linalg.svd(M, full_matrices=False)
    S = torch.cat([S[:keep], torch.clamp(S[keep:] - tau, min=0.0)])
    r = int((S > 0).sum())
    return (U[:, :r] * S[:r].to(U.dtype)) @ Vh[:r], r


def orthonormalize(A: Tensor) -> Tensor:
    """Q factor of the thin QR of ``A`` (column-orthonormal, same shape)."""
    return torch.linalg.qr(A, mode="reduced").Q


def interp_linear(M: Tensor, observed: Tensor) -> Tensor:
    """Linear interpolation of every column of ``M`` (T x N) along time over its unobserved rows.

    Before the first and after the last observed sample the nearest observed value is held
    (no extrapolation). Columns with no observation at all become 0. Vectorized, device-agnostic.
    """
    T = M.shape[0]
    t = torch.arange(T, device=M.device).unsqueeze(1).expand_as(M)
    prev = torch.cummax(torch.where(observed, t, -1), dim=0).values
    nxt = T - 1 - torch.cummax(torch.where(observed, T - 1 - t, -1).flip(0), dim=0).values.flip(0)
    has_prev, has_next = prev >= 0, nxt <= T - 1
    p, n = prev.clamp(min=0), nxt.clamp(max=T - 1)
    Mz = torch.where(observed, M, torch.zeros((), dtype=M.dtype, device=M.device))
    vp, vn = Mz.gather(0, p), Mz.gather(0, n)
    span = (n - p).clamp(min=1).to(M.dtype)
    w = ((t - p).to(M.dtype) / span).clamp(0.0, 1.0)
    lin = vp + w * (vn - vp)
    out = torch.where(has_prev & has_next, lin, torch.where(has_prev, vp, vn))
    out = torch.where(has_prev | has_next, out, torch.zeros((), dtype=M.dtype, device=M.device))
    return torch.where(observed, M, out)
