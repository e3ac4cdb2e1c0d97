"""The fill's finishing step from the QC (torchfill/qc/finish.py): short interior gaps kept on the
interpolation when the fill departs from it, and an error estimate no larger than what the fill
can be off."""
from __future__ import annotations

import numpy as np
import pytest
import warnings

import torchfill
from torchfill.qc import finish


def _walk(T=300, J=4, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 100.0
    return 300 * np.sin(2 * np.pi * (0.4 + 0.3 * rng.random((1, J, 3))) * t + rng.random((1, J, 3)))


def test_a_short_gap_filled_off_the_interpolation_gets_the_interpolation():
    X = _walk()
    gappy = X.copy()
    gappy[100:104, 1] = np.nan            # short: 4 frames at 100 Hz
    gappy[200:230, 2] = np.nan            # long: left to the fill
    filled = X.copy()
    filled[100:104, 1] += 40.0            # the short gap's fill 40 mm off
    filled[200:230, 2] += 40.0
    F, changed = finish.short_gap_fallback(gappy, filled, 100.0)
    assert changed == [(1, 100, 104)]
    err = np.linalg.norm(F[100:104, 1] - X[100:104, 1], axis=1)
    assert err.max() < 1.0                # the interpolation is right on a smooth short gap
    keep = np.ones(X.shape[:2], dtype=bool)
    keep[100:104, 1] = False
    assert np.array_equal(F[keep], filled[keep])
    close = X.copy()
    close[100:104, 1] += 0.5               # within AGREE_MM of it: kept
    assert finish.short_gap_fallback(gappy, close, 100.0)[1] == []
    assert finish.short_gap_fallback(gappy, filled, 20.0)[1] == []        # 4 frames > 0.1 s


def test_the_estimate_bound_holds_the_true_error_on_a_real_recording(recording):
    """Real walking (HDM05) with simulated gaps at the trial start, end and inside: every filled
    sample's true 3-D error is within sqrt(3) x the bound, and a huge estimate is cut to it."""
    seq = torchfill.read(recording("hdm05_bd_05-01_01_120.c3d"))
    X = seq.points[:600]
    gappy = X.copy()
    gappy[:12, 3] = np.nan
    gappy[588:, 7] = np.nan
    gappy[300:306, 11] = np.nan
    filled = X.copy()
    missing = np.isnan(gappy).any(axis=2)
    filled[missing] += 0.01 * np.linalg.norm(X.max(axis=(0, 1)) - X.min(axis=(0, 1)))
    bound = finish.std_bound(gappy, filled)
    assert np.isinf(bound[~missing]).all() and np.isfinite(bound[missing]).all()
    err = np.linalg.norm(filled - X, axis=2)
    assert (err[missing] <= np.sqrt(3) * bound[missing] + 1e-9).all()
    huge = np.where(missing, 1e6, np.nan)
    assert np.array_equal(np.fmin(huge, bound)[missing], bound[missing])


@pytest.mark.slow
def test_the_default_keeps_the_tennis_short_gap_on_its_interpolation(recording):
    """ktk_tennis_serve_nan against its clean twin: the 4-frame RSHO gap the default filled 70 mm
    from the interpolation across it (44 mm RMS from the truth) holds the interpolation (28 mm)."""
    gappy = torchfill.read(recording("ktk_tennis_serve_nan.c3d"))
    truth = torchfill.read(recording("ktk_tennis_serve.c3d")).points
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, std = torchfill.fill(gappy, return_std=True)
    assert out.meta["fill_info"]["short_gaps"] >= 1
    j = gappy.labels.index("Derrick:RSHO")
    a, b = 193 - gappy.first_frame, 197 - gappy.first_frame
    assert np.isnan(gappy.points[a:b, j]).all()
    err = 1000 * np.sqrt(np.mean(np.sum((out.points[a:b, j] - truth[a:b, j]) ** 2, axis=1)))
    assert err < 30.0
    seen = ~gappy.mask
    assert np.array_equal(out.points[seen], gappy.points[seen])
