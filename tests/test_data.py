"""The embedded sample recording and its generator."""
from __future__ import annotations

import numpy as np
import pytest

import torchfill
from torchfill import gaps, metrics
from torchfill.data import load_sample, sample_path, synthetic_walk
from torchfill.data.synth import LABELS


@pytest.fixture(scope="module")
def sample():
    return load_sample()


def test_sample_is_shipped_small_and_complete(sample):
    path = sample_path()
    assert path.is_file() and path.suffix == ".c3d"
    assert path.stat().st_size < 1_000_000
    assert sample.points.shape == (960, 41, 3)
    assert sample.short_labels() == LABELS
    assert sample.rate == 120.0 and sample.units == "mm"
    assert np.isfinite(sample.points).all()


def test_sample_is_what_the_generator_makes(sample):
    """The shipped file is ``synthetic_walk(seed=0)`` (stored as float32)."""
    np.testing.assert_allclose(sample.points, synthetic_walk().points, rtol=0, atol=1e-3)


def test_generator_is_deterministic_and_seeded():
    a, b = synthetic_walk(seconds=2.0), synthetic_walk(seconds=2.0)
    np.testing.assert_array_equal(a.points, b.points)
    c = synthetic_walk(seconds=2.0, seed=1)
    assert not np.array_equal(a.points, c.points)
    assert np.abs(a.points - c.points).max() < 50.0      # same walk, other noise and footprints
    assert synthetic_walk(seconds=1.0, rate=100.0).points.shape == (100, 41, 3)
    with pytest.raises(ValueError):
        synthetic_walk(seconds=0.0)


def test_sample_has_adult_walking_sizes(sample):
    P = sample.points
    at = {name: i for i, name in enumerate(sample.short_labels())}
    waist = P[:, [at[m] for m in ("LFWT", "RFWT", "LBWT", "RBWT")]].mean(axis=1)
    assert 900 < waist[:, 2].mean() < 1050                # pelvis ~0.95 m high, Z up
    assert 20 < np.ptp(waist[:, 2]) < 90                  # vertical bob
    speed = np.linalg.norm(np.diff(waist[:, :2], axis=0), axis=1).mean() * sample.rate
    assert 1000 < speed < 1500                            # mm/s
    assert P[:, at["LFHD"], 2].min() > 1500               # head above 1.5 m
    assert P[:, [at["LHEE"], at["RHEE"], at["LTOE"], at["RTOE"]], 2].min() > 0   # above floor
    # a heel on the floor does not slide (noise 0.3 mm only)
    noiseless = synthetic_walk(noise=0.0).points
    heel = noiseless[:, at["LHEE"]]
    planted = np.abs(heel[1:, 2] - 40.0) < 0.01          # foot flat: heel marker 40 mm high
    assert planted.mean() > 0.2
    assert np.abs(np.diff(heel[:, :2], axis=0))[planted].max() < 1.0


def test_linear_interpolation_error_on_sample_is_realistic(sample):
    """Same protocol as the CMU test in test_fill.py; measured 59.3 mm (CMU 02_01: 62.1 mm)."""
    P = sample.points
    errors = []
    for seed in range(5):
        mask = gaps.continuous_runs(*P.shape[:2], n_markers=10, gap_length=60, seed=seed)
        out = torchfill.fill(np.where(mask[..., None], np.nan, P), method="linear",
                             constraints=False)
        errors.append(metrics.rmse_missing(out, P, mask))
    assert 30.0 < np.mean(errors) < 1.5 * 59.3


def test_data_dir_env_first_then_beside_the_checkout(tmp_path, monkeypatch):
    from torchfill.data import data_dir
    monkeypatch.delenv("TORCHFILL_DATA", raising=False)
    assert data_dir(tmp_path / "repo") == (tmp_path / "shared" / "data").resolve()
    monkeypatch.setenv("TORCHFILL_DATA", str(tmp_path / "elsewhere"))
    assert data_dir(tmp_path / "repo") == (tmp_path / "elsewhere").resolve()
