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
    F, changed, departure = finish.short_gap_fallback(gappy, filled, 100.0)
    assert changed == [(1, 100, 104)]
    assert np.allclose(departure[100:104, 1], np.linalg.norm(filled[100:104, 1] - F[100:104, 1],
                                                             axis=1))
    assert np.isnan(departure[200:230, 2]).all()          # long: not compared
    err = np.linalg.norm(F[100:104, 1] - X[100:104, 1], axis=1)
    assert err.max() < 1.0                # the interpolation is right on a smooth short gap
    keep = np.ones(X.shape[:2], dtype=bool)
    keep[100:104, 1] = False
    assert np.array_equal(F[keep], filled[keep])
    close = X.copy()
    close[100:104, 1] += 0.5               # within AGREE_MM of it: kept
    kept, none, near = finish.short_gap_fallback(gappy, close, 100.0)
    assert none == [] and np.array_equal(kept, close)
    assert (near[100:104, 1] < 2.0).all()                 # compared, kept
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


def test_a_short_gap_whose_fill_departs_from_the_interpolation_is_flagged_on_a_real_recording(
        recording):
    """Real tennis serve (50 Hz, metres): a 4-frame interior gap of the upper arm whose fill
    departs up to 30 mm from the interpolation across it, with an estimate of 1 mm, is finished
    onto the interpolation with its estimate raised to the departure (at most the bound), and
    the QC flags it on that estimate; gaps filled on the truth keep a small estimate and are ok;
    observed samples never change."""
    from torchfill import qc

    seq = torchfill.read(recording("ktk_tennis_serve.c3d"))
    X, names = seq.points, list(seq.labels)
    arm, ankle, c7, knee = (names.index(f"Derrick:{m}") for m in ("RUPA", "LANK", "C7", "LKNE"))
    gappy = X.copy()
    gappy[300:304, arm] = gappy[200:204, ankle] = gappy[500:503, c7] = gappy[700:704, knee] = np.nan
    missing = np.isnan(gappy).any(axis=2)
    filled = X.copy()
    filled[300:304, arm, 0] += np.array([15.0, 30.0, 30.0, 15.0]) / 1000
    std = np.where(missing, 0.001 / np.sqrt(3), np.nan)            # 1 mm 3-D
    F, S, changed = finish.finish(gappy, filled, std, seq.rate, per_mm=0.001)
    assert (arm, 300, 304) in changed and (c7, 500, 503) not in changed
    assert np.array_equal(F[~missing], X[~missing])
    departure = np.linalg.norm(filled[300:304, arm] - F[300:304, arm], axis=1)
    raised = np.minimum(departure / np.sqrt(3), finish.std_bound(gappy, F)[300:304, arm])
    assert np.allclose(S[300:304, arm], raised) and (departure > 0.010).any()
    rows = {(r["j"], r["start"]): r for r in qc.gap_table(gappy, F, seq.rate, names, std=S,
                                                          units=seq.units)}
    off = rows[(arm, 300)]
    assert off["verdict"] in ("check", "reject") and off["est_rmse"] > 0.001 * qc.EST_CHECK_MM
    assert any("estimated error" in r for r in off["reasons"])
    assert all(rows[g]["verdict"] == "ok" for g in ((ankle, 200), (c7, 500), (knee, 700)))


@pytest.mark.slow
def test_the_default_keeps_the_tennis_short_gap_on_its_interpolation(recording):
    """ktk_tennis_serve_nan against its clean twin: the 4-frame RSHO gap the default filled 70 mm
    from the interpolation across it (44 mm RMS from the truth) holds the interpolation (28 mm),
    and its estimate says so: the QC flags it."""
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
    from torchfill import qc

    rows = qc.gap_table(gappy.points, out.points, gappy.rate, list(gappy.labels), std=std,
                        units=gappy.units)
    rsho = next(r for r in rows if r["j"] == j and r["start"] == a)
    assert rsho["verdict"] != "ok" and rsho["est_rmse"] > 0.001 * err      # flagged, not hidden
    seen = ~gappy.mask
    assert np.array_equal(out.points[seen], gappy.points[seen])
