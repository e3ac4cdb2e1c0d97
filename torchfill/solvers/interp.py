"""Interpolation baselines along time, per marker coordinate: what practitioners use today.

Each gap is interpolated from the observed samples of its own column (marker coordinate). Before
the first and after the last observed sample the nearest observed value is held, never
extrapolated. These are one-shot solvers: ``step()`` does the whole fill.
"""
from __future__ import annotations

import numpy as np
import torch

from .. import ops
from .base import OneShotSolver, register


class _Interpolator(OneShotSolver):
    def _initialize(self) -> None:
        self.X_ = self.M_.clone()

    def step(self) -> dict[str, float]:
        shape = self.M_.shape
        M = self.M_.reshape(shape[0], -1)
        W = self.Omega_.reshape(shape[0], -1)
        self.X_ = self._interpolate(M, W).reshape(shape)
        return {"delta": 0.0}

    def _estimate(self) -> torch.Tensor:
        return self.X_

    def _interpolate(self, M: torch.Tensor, W: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError


@register
class Linear(_Interpolator):
    """Linear interpolation in time (nearest observed value held at the ends)."""

    name = "linear"

    def _interpolate(self, M, W):
        return ops.interp_linear(M, W)


class _ScipyInterpolator(_Interpolator):
    """Piecewise-cubic interpolation per column through SciPy (runs once, on the CPU)."""

    kind: str       # the scipy.interpolate class, imported on first use (0.8 s: not for every fill)

    def _interpolate(self, M, W):
        import scipy.interpolate

        kind = getattr(scipy.interpolate, self.kind)
        out = ops.interp_linear(M, W)  # ends held, unobserved columns 0
        Mn, Wn, On = M.cpu().numpy(), W.cpu().numpy(), out.cpu().numpy().copy()
        t = np.arange(M.shape[0])
        for j in range(M.shape[1]):
            obs = Wn[:, j]
            if obs.sum() < 3 or obs.all():
                continue
            inside = ~obs & (t > t[obs][0]) & (t < t[obs][-1])
            On[inside, j] = kind(t[obs], Mn[obs, j])(t[inside])
        return torch.as_tensor(On, dtype=M.dtype, device=M.device)


@register
class Spline(_ScipyInterpolator):
    """Cubic spline (not-a-knot) through all observed samples of the column."""

    name = "spline"
    kind = "CubicSpline"


@register
class Pchip(_ScipyInterpolator):
    """Shape-preserving piecewise cubic Hermite interpolation (no overshoot)."""

    name = "pchip"
    kind = "PchipInterpolator"
