"""Rotations: the batched least-squares rotation of corresponding point sets (Kabsch's problem,
solved by Horn's quaternion with Theobald's characteristic polynomial).

References
----------
Kabsch, W. (1976). A solution for the best rotation to relate two sets of vectors.
Acta Crystallographica A 32(5), 922-923.
Horn, B. K. P. (1987). Closed-form solution of absolute orientation using unit quaternions.
JOSA A 4(4), 629-642.
Theobald, D. L. (2005). Rapid calculation of RMSDs using a quaternion-based characteristic
polynomial. Acta Crystallographica A 61(4), 478-480.
"""
from __future__ import annotations

import torch

Tensor = torch.Tensor

__all__ = ["kabsch"]


def kabsch(P: Tensor, Q: Tensor, w: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Least-squares rotation ``R`` and translation ``t`` with ``Q ~ P @ R.T + t``, batched.

    ``P``, ``Q``: ``(n, k, 3)`` corresponding points, finite (k >= 3, not collinear); ``w``:
    optional ``(n, k)`` non-negative weights (zero: that point is left out). Returns ``R``
    ``(n, 3, 3)`` (a proper rotation, det +1) and ``t`` ``(n, 3)``. The rotation is Horn's (1987)
    unit quaternion, the top eigenvector of a 4 x 4 matrix, from the largest root of its
    characteristic polynomial (Theobald 2005): elementwise arithmetic over the batch, a fraction
    of a batched SVD's or eigh's time. Each item's result depends on its own points only (not on
    the batch around it).
    """
    if w is None:
        w = torch.ones(P.shape[:2], dtype=P.dtype, device=P.device)
    if P.shape[0] == 0:
        return P.new_zeros((0, 3, 3)), P.new_zeros((0, 3))
    parts = [_kabsch(P[a:a + HORN_BLOCK], Q[a:a + HORN_BLOCK], w[a:a + HORN_BLOCK])
             for a in range(0, P.shape[0], HORN_BLOCK)]
    return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])


#: Rotations are solved this many at a time (arrays that stay in the CPU's cache).
HORN_BLOCK = 8192


def _kabsch(P: Tensor, Q: Tensor, w: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`kabsch` of one block."""
    w = w / w.sum(dim=1, keepdim=True).clamp(min=torch.finfo(w.dtype).tiny)
    cp, cq = torch.bmm(w[:, None], P), torch.bmm(w[:, None], Q)          # centroids (n, 1, 3)
    P, Q = P - cp, Q - cq
    Pw = P * w[..., None]
    H = Pw.transpose(1, 2) @ Q                                          # cross-covariance
    QQ = Q * Q                  # the squared norms added as torch's sum over 3 adds them, faster
    E0 = 0.5 * ((Pw * P).sum(dim=(1, 2)) + (w * (QQ[..., 0] + QQ[..., 1] + QQ[..., 2])).sum(dim=1))
    R = _horn(H, E0)
    t = (cq - cp @ R.transpose(1, 2))[:, 0]
    return R, t


def _det3(a, b, c, d, e, f, g, h, i):
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _minors(A):
    """The 2 x 2 minors of rows 0-1 and of rows 2-3 of the 4 x 4 ``A`` (lists of lists), in the
    order of the Laplace expansion of its determinant along those rows."""
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    s = [A[0][a] * A[1][b] - A[0][b] * A[1][a] for a, b in pairs]
    c = [A[2][a] * A[3][b] - A[2][b] * A[3][a] for a, b in pairs]
    return s, c


def _adjugate_rows(A, s, c):
    """The adjugate of the symmetric 4 x 4 ``A`` from its minors (:func:`_minors`), as four rows
    of four (cofactor expansion)."""
    r0 = [A[1][1] * c[5] - A[1][2] * c[4] + A[1][3] * c[3],
          -A[0][1] * c[5] + A[0][2] * c[4] - A[0][3] * c[3],
          A[3][1] * s[5] - A[3][2] * s[4] + A[3][3] * s[3],
          -A[2][1] * s[5] + A[2][2] * s[4] - A[2][3] * s[3]]
    r1 = [r0[1], A[0][0] * c[5] - A[0][2] * c[2] + A[0][3] * c[1],
          -A[3][0] * s[5] + A[3][2] * s[2] - A[3][3] * s[1],
          A[2][0] * s[5] - A[2][2] * s[2] + A[2][3] * s[1]]
    r2 = [r0[2], r1[2], A[3][0] * s[4] - A[3][1] * s[2] + A[3][3] * s[0],
          -A[2][0] * s[4] + A[2][1] * s[2] - A[2][3] * s[0]]
    r3 = [r0[3], r1[3], r2[3], A[2][0] * s[3] - A[2][1] * s[1] + A[2][2] * s[0]]
    return [r0, r1, r2, r3]


def _horn(H: Tensor, E0: Tensor) -> Tensor:
    """The proper rotations ``R`` (n, 3, 3) maximizing ``tr(R H)`` for cross-covariances ``H``
    (n, 3, 3): Horn's matrix ``N``, its largest eigenvalue by Newton's method on the
    characteristic polynomial from the upper bound ``E0`` (Theobald 2005, Eq. 6-12; each item
    stops at its own convergence), the eigenvector from the adjugate of ``N - lambda I`` (its row
    with the largest diagonal entry). Where that root is (nearly) double -- collinear mates, the
    turn about their line unseen -- ``torch.linalg.eigh`` decides."""
    Sxx, Sxy, Sxz, Syx, Syy, Syz, Szx, Szy, Szz = H.reshape(-1, 9).T.contiguous().unbind(0)
    N = [[Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx],            # Horn (1987), Eq. 30
         [Syz - Szy, Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz],
         [Szx - Sxz, Sxy + Syx, -Sxx + Syy - Szz, Syz + Szy],
         [Sxy - Syx, Szx + Sxz, Syz + Szy, -Sxx - Syy + Szz]]
    c2 = -2.0 * (H * H).sum(dim=(1, 2))                                  # Theobald Eq. 8-10
    c1 = -8.0 * _det3(Sxx, Sxy, Sxz, Syx, Syy, Syz, Szx, Szy, Szz)
    s, c = _minors(N)
    c0 = s[0] * c[5] - s[1] * c[4] + s[2] * c[3] + s[3] * c[2] - s[4] * c[1] + s[5] * c[0]
    lam = E0.clone()
    tol = 1e-13 * E0.abs()
    moving = torch.ones_like(lam, dtype=torch.bool)
    for _ in range(NEWTON_STEPS):                                        # Theobald Eq. 12
        l2 = lam * lam
        dp = (4.0 * l2 + 2.0 * c2) * lam + c1
        step = torch.where(moving & (dp > 0), ((l2 + c2) * l2 + c1 * lam + c0) / dp, 0.0)
        lam = lam - step
        moving &= step.abs() > tol
        if not bool(moving.any()):
            break
    A = [[N[i][j] - lam if i == j else N[i][j] for j in range(4)] for i in range(4)]
    C = torch.stack([c for row in _adjugate_rows(A, *_minors(A)) for c in row], -1).view(-1, 4, 4)
    pick = torch.diagonal(C, dim1=-2, dim2=-1).abs().argmax(dim=-1)
    q = C[torch.arange(C.shape[0]), pick]
    best = (q * q).sum(dim=-1)
    weak = ~(best > (1e-8 * E0 ** 3) ** 2) | moving                    # a double root
    if bool(weak.any()):
        Nw = torch.stack([torch.stack(row, -1) for row in N], -2)[weak]
        q[weak] = torch.linalg.eigh(Nw).eigenvectors[..., -1]
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                       -1).view(-1, 3, 3)


#: Newton steps on the characteristic polynomial at most (a good fit converges in four).
NEWTON_STEPS = 60
