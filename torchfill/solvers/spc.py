"""SPC: smooth PARAFAC completion (Yokota, Zhao & Cichocki 2016), a baseline of the CP paper.

The model is a CP tensor ``sum_r g_r u_r(1) o u_r(2) o u_r(3)`` with unit factor vectors, fitted
to the observed entries (EM-style completion ``Y = P_Omega(T) + P_Omega^c(X)``) with a smoothness
penalty ``g_r^2 sum_n rho_n ||L u_r(n)||_p^p`` on each factor (``L`` the first difference):
``p = 2`` quadratic variation (SPC-QV) or ``p = 1`` total variation (SPC-TV). One component and
one mode at a time (HALS), with the rank growing one component at a time (their FR-SPC).

What this shares with :mod:`torchfill.solvers.cp` (and why): the CP paper's Algorithm 1 *is*
SPC's fully-rank-increasing HALS loop with other column updates, so SPC reuses that loop
(``_HALSCP``: completion step, rank increase on a stall of the observed residual, rank chosen on
held-out observed entries, the honest replacement of FR-SPC's noise-level stopping rule, which
needs the noise level). Only the column update is SPC's:

* QV: ``u = (I + rho_n L^T L)^{-1} z / g_r``, normalized (the closed form of SPC's QV update;
  applied by FFT through :func:`torchfill.solvers.cp.smoothing_filter`);
* TV: ``u = argmin 1/2 ||u - z / g_r||^2 + rho_n ||L u||_1``, normalized, solved by Chambolle's
  dual projection (SPC solves its TV sub-problem iteratively too).

``z = Y_r x_{-n} {u_r}`` is the residue contraction. The penalty is on the time mode only by
default: the marker order and the xyz axes have no neighbourhood (SPC smooths image rows and
columns, which do).

References
----------
T. Yokota, Q. Zhao and A. Cichocki, "Smooth PARAFAC decomposition for tensor completion",
IEEE Trans. Signal Process. 64(20), 5423-5436, 2016.
A. Chambolle, "An algorithm for total variation minimization and applications", J. Math.
Imaging Vis. 20, 89-97, 2004.
"""
from __future__ import annotations

import torch

from .base import Param, register
from .cp import _TINY, _HALSCP, _signed, smoothing_filter

Tensor = torch.Tensor


def tv_denoise(z: Tensor, rho: float, n_iter: int) -> Tensor:
    """``argmin_u 1/2 ||u - z||^2 + rho ||L u||_1`` (1-D total variation, ``L`` first
    differences) by Chambolle's projection on the dual ``p`` (``|p_i| <= rho``), step 1/4."""
    if z.shape[0] < 2 or rho == 0.0:
        return z
    p = torch.zeros_like(z[1:])
    for _ in range(n_iter):
        u = z + torch.cat([p[:1], p[1:] - p[:-1], -p[-1:]])     # u = z - L^T p
        p = torch.clamp(p + 0.25 * (u[1:] - u[:-1]), -rho, rho)
    return z + torch.cat([p[:1], p[1:] - p[:-1], -p[-1:]])


@register
class SPC(_HALSCP):
    """SPC (Yokota et al. 2016): smooth PARAFAC completion, QV or TV smoothness, rank grown
    one component at a time (FR-SPC), rank chosen on held-out observed entries.

    Parameters
    ----------
    rho, variant, rho_modes, tv_iter
        SPC's smoothness weights ``rho_n`` (relative to ``g_r^2``, so scale-free), ``p``, the
        modes that carry them and the inner TV iterations; the rank parameters are the CP
        family's (see ``SPC.declared_params()``).

    References
    ----------
    T. Yokota, Q. Zhao and A. Cichocki, IEEE Trans. Signal Process. 64(20), 2016.
    """

    name = "spc"
    params = {
        "rho": Param(1.0, float, low=0.0,
                     doc="rho_n, the smoothness weight relative to g_r^2 (SPC's penalty scale); "
                         "chosen on CMU 02_01 at 120 Hz"),
        "variant": Param("qv", str, choices=("qv", "tv"),
                         doc="qv: quadratic variation (p = 2); tv: total variation (p = 1)"),
        "rho_modes": Param((0,), (tuple, list),
                           doc="modes (0 = time, 1 = markers, 2 = xyz) that carry rho"),
        "tv_iter": Param(30, int, low=1, doc="Chambolle iterations per TV column update"),
    }

    def _update_column(self, g: Tensor, a: Tensor, lam_r: Tensor, n: int) -> Tensor:
        if n not in self.rho_modes or self.rho == 0.0:
            return g                                        # plain HALS column (no penalty)
        z = g / lam_r.clamp_min(_TINY)
        if self.variant == "qv":
            u = smoothing_filter(z, self.rho / 2.0)          # (I + rho L^T L)^{-1} z
        else:
            u = tv_denoise(z, self.rho / (2.0 * z.shape[0] ** 0.5), self.tv_iter)
        self.inner_steps_ += 1
        return _signed(g, u / u.norm().clamp_min(_TINY))
