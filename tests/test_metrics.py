"""Metrics against an independent plain-Python loop reference, plus their defining properties."""
from __future__ import annotations

import math

import numpy as np
import pytest

from torchfill import metrics


def _case(seed: int, T: int = 37, J: int = 6, rate: float = 0.3):
    rng = np.random.default_rng(seed)
    truth = rng.normal(0.0, 100.0, size=(T, J, 3))
    mask = rng.random((T, J)) < rate
    filled = truth + rng.normal(0.0, 10.0, size=truth.shape) * mask[..., None]
    # observed entries of ``filled`` differ from truth too: they must not count
    filled = filled + rng.normal(0.0, 5.0, size=truth.shape) * ~mask[..., None]
    return filled, truth, mask


def _errors(filled, truth, mask):
    """Per-entry errors, observed entries zero, as a flat Python list (the reference's input)."""
    T, J, _ = truth.shape
    out = []
    for t in range(T):
        for j in range(J):
            for c in range(3):
                out.append(float(filled[t, j, c] - truth[t, j, c]) if mask[t, j] else 0.0)
    return out


def ref_rmse(filled, truth, mask):
    e = _errors(filled, truth, mask)
    return math.sqrt(sum(x * x for x in e) / len(e))


def ref_ave(filled, truth, mask):
    e = _errors(filled, truth, mask)
    return sum(abs(x) for x in e) / len(e)


def ref_std(filled, truth, mask):
    a = [abs(x) for x in _errors(filled, truth, mask)]
    mean = sum(a) / len(a)
    return math.sqrt(sum((x - mean) ** 2 for x in a) / len(a))


def ref_rmse_missing(filled, truth, mask):
    total, n = 0.0, 0
    T, J, _ = truth.shape
    for t in range(T):
        for j in range(J):
            if mask[t, j]:
                for c in range(3):
                    total += (filled[t, j, c] - truth[t, j, c]) ** 2
                    n += 1
    return math.sqrt(total / n) if n else 0.0


def ref_gap_runs(mask):
    runs = []
    T, J = mask.shape
    for j in range(J):
        t = 0
        while t < T:
            if mask[t, j]:
                start = t
                while t < T and mask[t, j]:
                    t += 1
                runs.append((j, start, t))
            else:
                t += 1
    return runs


def ref_gap_error(filled, truth, mask):
    per_gap = []
    for j, a, b in ref_gap_runs(mask):
        d = [math.sqrt(sum((filled[t, j, c] - truth[t, j, c]) ** 2 for c in range(3)))
             for t in range(a, b)]
        per_gap.append(sum(d) / len(d))
    return sum(per_gap) / len(per_gap) if per_gap else 0.0


def ref_frame_rmse(filled, truth, mask):
    out = []
    for t in range(truth.shape[0]):
        sq = [(filled[t, j, c] - truth[t, j, c]) ** 2
              for j in range(truth.shape[1]) if mask[t, j] for c in range(3)]
        out.append(math.sqrt(sum(sq) / len(sq)) if sq else math.nan)
    return np.array(out)


REFERENCES = {
    "rmse": ref_rmse, "ave": ref_ave, "std": ref_std,
    "rmse_missing": ref_rmse_missing, "gap_error": ref_gap_error,
}


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("name", sorted(REFERENCES))
def test_metric_matches_loop_reference(name, seed):
    filled, truth, mask = _case(seed)
    got = getattr(metrics, name)(filled, truth, mask)
    assert isinstance(got, float)
    assert got == pytest.approx(REFERENCES[name](filled, truth, mask), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_frame_rmse_matches_loop_reference(seed):
    filled, truth, mask = _case(seed, rate=0.1)
    mask[5] = False                                  # a frame with nothing missing -> NaN
    got = metrics.frame_rmse(filled, truth, mask)
    want = ref_frame_rmse(filled, truth, mask)
    assert got.shape == (truth.shape[0],)
    assert np.isnan(got[5])
    np.testing.assert_allclose(got, want, rtol=1e-12, equal_nan=True)


@pytest.mark.parametrize("seed", range(3))
def test_gap_runs_matches_loop_reference(seed):
    _, _, mask = _case(seed, rate=0.5)
    mask[-1, 0] = mask[0, 1] = True                  # runs touching both ends
    assert metrics.gap_runs(mask) == ref_gap_runs(mask)


def test_score_returns_every_scalar_metric():
    filled, truth, mask = _case(7)
    s = metrics.score(filled, truth, mask)
    assert set(s) == set(REFERENCES)
    for name, value in s.items():
        assert value == pytest.approx(REFERENCES[name](filled, truth, mask), rel=1e-12)


def test_zero_error_when_filled_equals_truth():
    _, truth, mask = _case(1)
    for name, value in metrics.score(truth, truth, mask).items():
        assert value == 0.0, name
    assert np.nansum(metrics.frame_rmse(truth, truth, mask)) == 0.0


def test_observed_entries_do_not_count():
    filled, truth, mask = _case(2)
    before = metrics.score(filled, truth, mask)
    wild = filled.copy()
    wild[~mask] = 1e9                                # garbage where the sample was observed
    assert metrics.score(wild, truth, mask) == before


def test_empty_mask_gives_zero():
    filled, truth, _ = _case(3)
    mask = np.zeros(truth.shape[:2], dtype=bool)
    assert all(v == 0.0 for v in metrics.score(filled, truth, mask).values())
    assert np.isnan(metrics.frame_rmse(filled, truth, mask)).all()


def test_all_entries_vs_missing_only_conventions():
    """rmse over all T*J*3 entries = rmse_missing scaled by sqrt(fraction missing)."""
    filled, truth, mask = _case(4)
    frac = mask.mean()
    assert metrics.rmse(filled, truth, mask) == pytest.approx(
        metrics.rmse_missing(filled, truth, mask) * math.sqrt(frac), rel=1e-12)


def test_known_value_one_gap():
    truth = np.zeros((4, 2, 3))
    filled = truth.copy()
    filled[1:3, 0] = [3.0, 4.0, 0.0]                 # 3-D error 5 on two frames of one gap
    mask = np.zeros((4, 2), dtype=bool)
    mask[1:3, 0] = True
    assert metrics.gap_error(filled, truth, mask) == pytest.approx(5.0)
    assert metrics.rmse_missing(filled, truth, mask) == pytest.approx(math.sqrt(50 / 6))
    assert metrics.rmse(filled, truth, mask) == pytest.approx(math.sqrt(50 / 24))
    assert metrics.ave(filled, truth, mask) == pytest.approx(14 / 24)


def test_shape_mismatch_raises():
    filled, truth, mask = _case(5)
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.rmse(filled[:-1], truth, mask)
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.rmse(filled, truth, mask[:, :-1])


def test_marker_jumps_counts_against_each_markers_own_steps():
    """A slow marker's 30 mm jump inside a fill counts against its own 1 mm steps, though a fast
    marker's 50 mm steps would hide it under the recording-wide limit."""
    T = 200
    t = np.arange(T, dtype=float)
    X = np.zeros((T, 2, 3))
    X[:, 0, 0] = t                                   # slow: 1 mm a frame
    X[:, 1, 0] = 50.0 * t                            # fast: 50 mm a frame
    missing = np.zeros((T, 2), dtype=bool)
    missing[100:120, 0] = True
    observed = ~missing
    F = X.copy()
    F[110:120, 0, 0] += 30.0                         # the fill jumps at frame 110 and stays
    assert metrics.teleports(F, missing, metrics.step_limit(X, observed)) == 0
    assert metrics.marker_jumps(F, missing, observed) == 2   # in at 110, back out at 120
    assert metrics.marker_jumps(X, missing, observed) == 0
