"""Degenerate data every method must survive: every coordinate equal, and two markers only.

A method either fills every gap (finite, observed samples bit for bit) or says in a warning which
samples it left; it never crashes with a raw linear-algebra error."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import torchfill

CHEAP = {"max_iter": 20}
METHODS = [m for m in torchfill.methods() if m != "auto"] + ["auto"]


def _params(method: str) -> dict:
    declared = torchfill.get_solver(method).declared_params()
    params = {k: v for k, v in CHEAP.items() if k in declared}
    if method == "auto":
        params["candidates"] = ["pchip", "svt", "pca_train"]
    return params


def _fill(X: np.ndarray, method: str):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = torchfill.fill(X, method, params=_params(method), constraints=False)
    said = [str(w.message) for w in caught if not issubclass(w.category, DeprecationWarning)]
    return out, said


@pytest.mark.parametrize("method", METHODS)
def test_every_coordinate_equal(method):
    X = np.full((60, 5, 3), 7.0)
    X[10:20, 1] = np.nan
    X[40:45, 3] = np.nan
    out, _ = _fill(X, method)
    gaps = np.isnan(X)
    assert np.array_equal(out[~gaps], X[~gaps])
    np.testing.assert_allclose(out[gaps], 7.0, atol=1e-6)          # the only sensible fill


@pytest.mark.parametrize("method", METHODS)
def test_two_markers_fill_or_warn(method):
    rng = np.random.default_rng(0)
    t = np.arange(200)[:, None, None] / 50.0
    truth = 100 * np.sin(t + rng.uniform(0, 6, (1, 2, 3))) + rng.normal(0, 500, (1, 2, 3))
    X = truth.copy()
    X[50:80, 1] = np.nan
    X[120:130, 0] = np.nan
    out, said = _fill(X, method)
    gaps = np.isnan(X)
    assert np.array_equal(out[~gaps], X[~gaps])
    left = np.isnan(out[gaps]).sum()
    assert left == 0 or any("unfilled" in s or "could not" in s for s in said), (left, said)
    done = np.isfinite(out) & gaps
    assert np.abs(out[done] - truth[done]).max() < 1000.0             # not wild: within the body
