"""Interpolation baselines: exactness on the data each one models, held ends, no overshoot."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchfill

INTERP = ["linear", "spline", "pchip"]


def fill(X, method, mask=None):
    return torchfill.fill(X, method=method, mask=mask, constraints=False)  # the method alone


def polynomial_motion(T: int, J: int, degree: int, seed: int = 0) -> np.ndarray:
    """Every coordinate a random polynomial of ``degree`` in time (mm-sized values)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(-1.0, 1.0, T)
    coef = rng.normal(0.0, 200.0, size=(degree + 1, J, 3))
    return sum(coef[k] * t[:, None, None] ** k for k in range(degree + 1)) + 500.0


def inner_gaps(T: int, J: int) -> np.ndarray:
    mask = np.zeros((T, J), dtype=bool)
    mask[10:30, 0] = True
    mask[40:41, 1] = True
    mask[15:60, 2] = True
    mask[5:8, 0] = mask[70:85, 1] = True
    return mask


@pytest.mark.parametrize("method", INTERP)
def test_ends_hold_the_nearest_observed_value(method):
    X = polynomial_motion(100, 3, degree=3)
    mask = np.zeros((100, 3), dtype=bool)
    mask[:12, 0] = True                                   # leading gap
    mask[85:, 1] = True                                   # trailing gap
    mask[:5, 2] = mask[95:, 2] = True                     # both
    out = fill(np.where(mask[..., None], np.nan, X), method)
    np.testing.assert_array_equal(out[:12, 0], np.broadcast_to(X[12, 0], (12, 3)))
    np.testing.assert_array_equal(out[85:, 1], np.broadcast_to(X[84, 1], (15, 3)))
    np.testing.assert_array_equal(out[:5, 2], np.broadcast_to(X[5, 2], (5, 3)))
    np.testing.assert_array_equal(out[95:, 2], np.broadcast_to(X[94, 2], (5, 3)))
    np.testing.assert_array_equal(out[~mask], X[~mask])


@pytest.mark.parametrize("method", ["linear", "pchip", "spline"])
def test_exact_on_linear_motion(method):
    X = polynomial_motion(90, 3, degree=1, seed=1)
    mask = inner_gaps(90, 3)
    out = fill(np.where(mask[..., None], np.nan, X), method)
    np.testing.assert_allclose(out, X, rtol=0, atol=1e-9)


def test_spline_exact_on_cubic_motion_and_linear_is_not():
    X = polynomial_motion(90, 3, degree=3, seed=2)
    mask = inner_gaps(90, 3)
    gappy = np.where(mask[..., None], np.nan, X)
    np.testing.assert_allclose(fill(gappy, "spline"), X, rtol=0, atol=1e-8)
    assert np.abs(fill(gappy, "linear") - X).max() > 1.0   # the check can fail


def test_pchip_does_not_overshoot_a_step_but_spline_rings():
    """A fast ramp onto a plateau, the plateau partly missing: PCHIP stays within the data and
    monotone; the not-a-knot spline rings (goes back and forth) in the gap."""
    T = 100
    t = np.arange(T, dtype=float)
    X = np.zeros((T, 1, 3))
    X[:, 0, 0] = np.clip((t - 40) * 20.0, 0.0, 100.0)        # rises to 100 by t = 45
    X[:, 0, 1] = 100.0 - np.clip((t - 40) * 30.0, 0.0, 150.0)  # falls to -50
    X[:, 0, 2] = np.tanh((t - 43) / 1.5) * 80.0
    mask = np.zeros((T, 1), dtype=bool)
    mask[47:62] = True
    gappy = np.where(mask[..., None], np.nan, X)
    out = fill(gappy, "pchip")
    for c in range(3):
        lo, hi = X[~mask[:, 0], 0, c].min(), X[~mask[:, 0], 0, c].max()
        assert lo - 1e-9 <= out[:, 0, c].min() and out[:, 0, c].max() <= hi + 1e-9
        d = np.diff(out[38:65, 0, c])
        assert (d >= -1e-9).all() or (d <= 1e-9).all()    # monotone through the gap
    spline = fill(gappy, "spline")
    for c in range(2):                                    # the check can fail: spline rings
        d = np.diff(spline[38:65, 0, c])
        assert (d > 1.0).any() and (d < -1.0).any()


def test_columns_are_interpolated_independently():
    X = polynomial_motion(60, 4, degree=2, seed=3)
    mask = np.zeros((60, 4), dtype=bool)
    mask[20:40, 1] = True
    gappy = np.where(mask[..., None], np.nan, X)
    for method in INTERP:
        whole = fill(gappy, method)
        alone = fill(gappy[:, 1:2], method)
        np.testing.assert_allclose(whole[:, 1:2], alone, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("method", ["spline", "pchip"])
def test_too_few_observations_fall_back_to_linear(method):
    X = polynomial_motion(30, 1, degree=2, seed=4)
    mask = np.ones((30, 1), dtype=bool)
    mask[[3, 20]] = False                                 # two observations only
    gappy = np.where(mask[..., None], np.nan, X)
    np.testing.assert_allclose(fill(gappy, method), fill(gappy, "linear"), atol=1e-9)


@pytest.mark.parametrize("method", INTERP)
def test_torch_input_keeps_dtype(method):
    X = torch.from_numpy(polynomial_motion(50, 2, degree=1, seed=5)).float()
    X[10:20, 0] = float("nan")
    out = fill(X, method)
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    torch.testing.assert_close(out[10:20, 0], torch.from_numpy(
        polynomial_motion(50, 2, degree=1, seed=5)).float()[10:20, 0], rtol=1e-5, atol=1e-3)
