"""Spectral building blocks: singular value thresholding (the prox of the nuclear norm), the SVD
through the small Gram matrix, energy ranks, and the soft threshold (the prox of the l1 norm)."""
from __future__ import annotations

import torch

Tensor = torch.Tensor


def soft_threshold(x: Tensor, tau: float | Tensor) -> Tensor:
    """Proximal operator of ``tau * ||x||_1``: ``sign(x) * max(|x| - tau, 0)``."""
    return torch.sign(x) * torch.clamp(x.abs() - tau, min=0.0)


def thin_side(X: Tensor) -> tuple[Tensor, bool]:
    """``X`` or ``X^T``, whichever has fewer columns, and whether it was transposed."""
    return (X.mT, True) if X.shape[0] < X.shape[1] else (X, False)


def gram_svd(X: Tensor) -> tuple[Tensor, Tensor]:
    """Singular values (descending) and right singular vectors of ``X`` (m x n, m >= n) from the
    eigendecomposition of ``X^T X`` (n x n). Cost O(m n^2) + O(n^3) instead of an m x n SVD."""
    lam, V = torch.linalg.eigh(X.mT @ X)
    lam, V = lam.flip(-1), V.flip(-1)
    return torch.sqrt(torch.clamp(lam, min=0.0)), V


def svt(M: Tensor, tau: float | Tensor, method: str = "full", keep: int = 0) -> tuple[Tensor, int]:
    """Singular value thresholding ``D_tau(M) = U max(S - tau, 0) V^T`` (prox of ``tau ||.||_*``).

    ``keep`` leading singular values are left untouched (partial SVT, the prox of ``tau`` times
    ``sum_{i > keep} sigma_i``, used by PSTNN); ``M`` may be complex with ``method="full"``.
    ``method="full"``: a thin ``torch.linalg.svd``. ``method="gram"``: ``M V diag(max(s - tau, 0)
    / s) V^T`` from the Gram matrix of the thinner side -- for a recording's ``T x 3J`` unfolding
    one 3J x 3J eigendecomposition instead of an SVD of the long matrix (squares the condition
    number: fine for thresholds well above the rounding level).
    Returns the thresholded matrix and the number of singular values kept.
    """
    if method == "full":
        U, S, Vh = torch.linalg.svd(M, full_matrices=False)
        S = torch.cat([S[:keep], torch.clamp(S[keep:] - tau, min=0.0)])
        r = int((S > 0).sum())
        return (U[:, :r] * S[:r].to(U.dtype)) @ Vh[:r], r
    if method != "gram" or keep:
        raise ValueError(f"svt: method expected 'full' or 'gram' (keep=0), found {method!r}")
    Z, transposed = thin_side(M)
    s, V = gram_svd(Z)
    r = int((s > tau).sum())
    s, V = s[:r], V[:, :r]
    if 2 * r < V.shape[0]:       # few kept: (Z V_r) diag(1 - tau/s) V_r^T, 2 m n r flops, not m n^2
        out = ((Z @ V) * ((s - tau) / s)) @ V.mT
    else:
        out = Z @ ((V * ((s - tau) / s)) @ V.mT)
    return (out.mT if transposed else out), r


def energy_rank(M: Tensor, energy: float) -> int:
    """Smallest ``r`` whose leading singular values of the matrix ``M`` hold a fraction ``energy``
    of ``||M||_F^2`` (1 for an empty or zero matrix)."""
    if M.numel() == 0:
        return 1
    s, _ = gram_svd(thin_side(M)[0])
    s2 = s ** 2
    share = torch.cumsum(s2, 0) / torch.clamp(s2.sum(), min=torch.finfo(M.dtype).tiny)
    return min(int((share < energy).sum()) + 1, s.shape[0])


def orthonormalize(A: Tensor) -> Tensor:
    """Q factor of the thin QR of ``A`` (column-orthonormal, same shape)."""
    return torch.linalg.qr(A, mode="reduced").Q
