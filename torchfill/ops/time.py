"""Along time (mode 1): interpolation starts, temporal difference operators, run-lengths of masks."""
from __future__ import annotations

import torch

Tensor = torch.Tensor


def interp_linear(M: Tensor, observed: Tensor) -> Tensor:
    """Linear interpolation of every column of ``M`` (T x N) along time over its unobserved rows.

    Before the first and after the last observed sample the nearest observed value is held
    (no extrapolation). Columns with no observation at all become 0. Vectorized, device-agnostic;
    only the columns with a gap are computed (the others are ``M``'s own).
    """
    if observed.shape == M.shape and M.ndim == 2 and M.shape[1] > 1:
        gapped = ~observed.all(0)
        n = int(gapped.sum())
        if n == 0:
            return M.clone()
        if n < M.shape[1]:
            out = M.clone()
            out[:, gapped] = _interp_columns(M[:, gapped], observed[:, gapped])
            return out
    return _interp_columns(M, observed)


def _interp_columns(M: Tensor, observed: Tensor) -> Tensor:
    """:func:`interp_linear` on every column."""
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


def interp_relative(M: Tensor, Omega: Tensor) -> Tensor:
    """Gaps of a ``(T, J, D)`` recording filled by linear interpolation **relative to the
    centroid** of the markers observed in each frame, ``X = c(t) + interp(M - c)``.

    Plain linear interpolation holds a marker still before its first and after its last observed
    frame; on a recording that travels (a walk) that puts a gap at the start hundreds of mm off.
    Holding the marker's offset from the body centroid instead follows the global motion. Only
    observed values are used.
    """
    T = M.shape[0]
    zero = torch.zeros((), dtype=M.dtype, device=M.device)
    count = Omega.to(M.dtype).sum(dim=1, keepdim=True)                          # (T, 1, D)
    c = torch.where(count > 0, torch.where(Omega, M, zero).sum(dim=1, keepdim=True)
                    / count.clamp(min=1), zero)
    c = interp_linear(c.reshape(T, -1), (count > 0).reshape(T, -1)).reshape(c.shape)
    Rel = torch.where(Omega, M - c, zero)
    Rel = interp_linear(Rel.reshape(T, -1), Omega.reshape(T, -1)).reshape(M.shape)
    return torch.where(Omega, M, Rel + c)


def difference(X: Tensor, order: int) -> Tensor:
    """``D_order X`` along time (rows): D1 x_t = x_{t+1} - x_t, D2 = D1 D1 (shape (T-order) x ...)."""
    return torch.diff(X, n=order, dim=0) if order < X.shape[0] else X[:0]


def difference_adjoint(Y: Tensor, order: int, T: int) -> Tensor:
    """``D_order^T Y`` for ``Y`` of shape (T-order) x N: the adjoint of :func:`difference`."""
    if Y.shape[0] == 0:
        return Y.new_zeros((T,) + tuple(Y.shape[1:]))
    for _ in range(order):
        pad = Y.new_zeros((1,) + tuple(Y.shape[1:]))
        Z = torch.cat([pad, Y, pad], 0)      # (D1^T y)_t = y_{t-1} - y_t, y_{-1} = y_{T-1} = 0
        Y = Z[:-1] - Z[1:]
    return Y


def difference_gram(a: Tensor) -> Tensor:
    """``D^T D a`` for the first difference ``D`` ((I-1) x I), in O(I) without forming ``D``."""
    return difference_adjoint(difference(a, 1), 1, a.shape[0])


def runs(mask: Tensor) -> list[tuple[int, int, int]]:
    """``(column, start, stop)`` of every run of True along time in a bool ``(T, N)`` tensor, column
    by column (stop exclusive). The run-lengths of gap and hold-out masks, computed on the CPU."""
    m = mask.to(torch.int8).cpu()
    pad = torch.zeros(1, m.shape[1], dtype=torch.int8)
    d = torch.diff(torch.cat([pad, m, pad]), dim=0)
    out = []
    for j in range(m.shape[1]):
        edges = torch.nonzero(d[:, j]).flatten().tolist()
        out.extend((j, a, b) for a, b in zip(edges[::2], edges[1::2]))
    return out
