"""Gap generators: shapes, counts, lengths, the protocols' placement rules, seeds, bad arguments."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from torchfill import gaps
from torchfill.metrics import gap_runs

FAST = settings(max_examples=60, deadline=None)


def runs_by_marker(mask):
    out: dict[int, list[tuple[int, int]]] = {}
    for j, a, b in gap_runs(mask):
        out.setdefault(j, []).append((a, b))
    return out


def assert_mask(mask, T, J):
    assert isinstance(mask, np.ndarray)
    assert mask.shape == (T, J)
    assert mask.dtype == np.bool_


# -- multi_gap (Tucker paper) -------------------------------------------------------------------
@FAST
@given(T=st.integers(20, 400), J=st.integers(1, 40), data=st.data())
def test_multi_gap_properties(T, J, data):
    n = data.draw(st.integers(1, J))
    L = data.draw(st.integers(1, T - 1))
    K = data.draw(st.integers(1, 8))
    seed = data.draw(st.integers(0, 2 ** 31))
    mask = gaps.multi_gap(T, J, n_markers=n, gap_length=L, max_gaps=K, seed=seed)
    assert_mask(mask, T, J)
    runs = runs_by_marker(mask)
    assert len(runs) == n                                   # exactly n markers affected
    window = max(1, min(int(T * 4 / 5.1), T - L + 1))       # authors' start window, gap must fit
    for j, rr in runs.items():
        assert len(rr) <= K                                 # at most K gaps (overlaps merge)
        for a, b in rr:
            assert b - a >= L                               # merged gaps only get longer
            assert a < window                               # every gap starts in the window
            assert b <= T
        total = mask[:, j].sum()
        assert L <= total <= K * L


def test_multi_gap_single_gap_has_exact_length():
    mask = gaps.multi_gap(500, 30, n_markers=12, gap_length=77, max_gaps=1, seed=3)
    runs = runs_by_marker(mask)
    assert len(runs) == 12
    assert all(rr == [(rr[0][0], rr[0][0] + 77)] for rr in runs.values())


def test_multi_gap_number_of_gaps_follows_K_rule():
    """K_m = max(1, round(U * K)), U uniform: with K = 5 every count 1..5 occurs, none above."""
    counts = []
    for seed in range(40):
        mask = gaps.multi_gap(3000, 40, n_markers=40, gap_length=2, max_gaps=5, seed=seed)
        counts += [len(rr) for rr in runs_by_marker(mask).values()]
    values, freq = np.unique(counts, return_counts=True)
    # short gaps on a long recording rarely merge, so run counts ~ gap counts
    assert set(values) <= set(range(1, 6)) and set(values) >= {1, 2, 3, 4, 5}
    # P(K=1) = P(U < 0.3) = 0.3 while P(K=5) = P(U >= 0.9) = 0.1
    assert freq[values == 1][0] > 2 * freq[values == 5][0]


def test_multi_gap_start_window_is_first_four_fifths():
    T, L = 1000, 10
    starts = [a for seed in range(20)
              for rr in runs_by_marker(gaps.multi_gap(T, 30, n_markers=30, gap_length=L,
                                                      max_gaps=3, seed=seed)).values()
              for a, _ in rr]
    assert max(starts) < int(T * 4 / 5.1)                   # 784: the demo's rule
    assert max(starts) > 0.7 * T                            # and the whole window is used
    assert min(starts) < 0.1 * T


# -- shared_window (CP paper) -------------------------------------------------------------------
@FAST
@given(T=st.integers(2, 300), J=st.integers(1, 30), data=st.data())
def test_shared_window_properties(T, J, data):
    n = data.draw(st.integers(1, J))
    L = data.draw(st.integers(1, T - 1))
    mask = gaps.shared_window(T, J, n_markers=n, gap_length=L, seed=data.draw(st.integers(0, 99)))
    assert_mask(mask, T, J)
    runs = runs_by_marker(mask)
    assert len(runs) == n
    spans = {tuple(rr) for rr in runs.values()}
    assert len(spans) == 1                                  # one window shared by all
    (a, b), = spans.pop()
    assert b - a == L and 0 <= a and b <= T


# -- evenly_spaced (Li et al.) ------------------------------------------------------------------
@FAST
@given(T=st.integers(10, 400), J=st.integers(1, 30), data=st.data())
def test_evenly_spaced_properties(T, J, data):
    L = data.draw(st.integers(1, T // 4))
    n_gaps = data.draw(st.integers(1, J))
    mask = gaps.evenly_spaced(T, J, n_gaps=n_gaps, gap_length=L, seed=data.draw(st.integers(0, 99)))
    assert_mask(mask, T, J)
    runs = runs_by_marker(mask)
    assert len(runs) == n_gaps                              # each gap on its own marker
    starts = sorted(a for rr in runs.values() for a, _ in rr)
    np.testing.assert_array_equal(starts, np.linspace(0, T - L, n_gaps).round().astype(int))
    assert all(b - a == L for rr in runs.values() for a, b in rr)


def test_evenly_spaced_reuses_markers_only_when_needed():
    mask = gaps.evenly_spaced(1000, 3, n_gaps=7, gap_length=20, seed=0)
    assert mask.any(axis=0).all()
    assert mask.sum() == 7 * 20                             # gaps far apart never overlap


# -- blackout (Li et al.) -----------------------------------------------------------------------
@FAST
@given(T=st.integers(4, 300), J=st.integers(1, 30), data=st.data())
def test_blackout_properties(T, J, data):
    L = data.draw(st.integers(1, T - 3))
    mask = gaps.blackout(T, J, gap_length=L, seed=data.draw(st.integers(0, 99)))
    assert_mask(mask, T, J)
    frames = np.flatnonzero(mask.any(axis=1))
    assert mask[frames].all()                               # whole frames
    assert len(frames) == L and np.all(np.diff(frames) == 1)
    assert frames[0] >= 1 and frames[-1] <= T - 2           # never the first or last frame


def test_blackout_explicit_start():
    mask = gaps.blackout(100, 5, gap_length=10, start=0)
    assert mask[:10].all() and not mask[10:].any()
    with pytest.raises(ValueError, match="start"):
        gaps.blackout(100, 5, gap_length=10, start=91)
    with pytest.raises(ValueError, match="start"):
        gaps.blackout(100, 5, gap_length=10, start=-1)


# -- random_entries and continuous_runs (Imamura & Okuda) ----------------------------------------
@pytest.mark.parametrize("rate", [0.0, 0.1, 0.5, 0.9])
def test_random_entries_rate(rate):
    T, J = 2000, 20
    mask = gaps.random_entries(T, J, rate=rate, seed=1)
    assert_mask(mask, T, J)
    n = T * J
    assert abs(mask.mean() - rate) <= 5 * np.sqrt(rate * (1 - rate) / n) + 1e-12
    assert (~mask).any(axis=0).all()                        # every marker keeps an observation


def test_random_entries_keeps_one_frame_per_marker_even_at_high_rate():
    mask = gaps.random_entries(3, 200, rate=0.99, seed=0)
    assert (~mask).any(axis=0).all()


@FAST
@given(T=st.integers(2, 300), J=st.integers(1, 30), data=st.data())
def test_continuous_runs_properties(T, J, data):
    n = data.draw(st.integers(1, J))
    L = data.draw(st.integers(1, T - 1))
    mask = gaps.continuous_runs(T, J, n_markers=n, gap_length=L,
                                seed=data.draw(st.integers(0, 99)))
    assert_mask(mask, T, J)
    runs = runs_by_marker(mask)
    assert len(runs) == n
    assert all(len(rr) == 1 and rr[0][1] - rr[0][0] == L for rr in runs.values())


# -- all protocols: seeds and dispatch -----------------------------------------------------------
KWARGS = {
    "multi_gap": dict(n_markers=5, gap_length=20, max_gaps=3),
    "shared_window": dict(n_markers=5, gap_length=20),
    "evenly_spaced": dict(n_gaps=5, gap_length=20),
    "blackout": dict(gap_length=20),
    "random_entries": dict(rate=0.2),
    "continuous_runs": dict(n_markers=5, gap_length=20),
}


def test_every_protocol_is_covered():
    assert set(gaps.PROTOCOLS) == set(KWARGS)


@pytest.mark.parametrize("name", sorted(KWARGS))
def test_seed_reproducible_and_different_seeds_differ(name):
    T, J = 300, 20
    a = gaps.generate(name, T, J, seed=11, **KWARGS[name])
    b = gaps.generate(name, T, J, seed=11, **KWARGS[name])
    np.testing.assert_array_equal(a, b)
    others = [gaps.generate(name, T, J, seed=s, **KWARGS[name]) for s in range(5)]
    assert any(not np.array_equal(a, o) for o in others)
    np.testing.assert_array_equal(a, gaps.PROTOCOLS[name](T, J, seed=11, **KWARGS[name]))


def test_generate_unknown_protocol():
    with pytest.raises(ValueError, match="unknown gap protocol 'nope'"):
        gaps.generate("nope", 10, 2)


BAD = [
    ("multi_gap", dict(n_markers=0), "n_markers"),
    ("multi_gap", dict(n_markers=21), "n_markers"),
    ("multi_gap", dict(n_markers=5, gap_length=0), "gap_length"),
    ("multi_gap", dict(n_markers=5, gap_length=300), "gap_length"),
    ("multi_gap", dict(n_markers=5, gap_length=10, max_gaps=0), "max_gaps"),
    ("shared_window", dict(n_markers=25), "n_markers"),
    ("shared_window", dict(gap_length=301), "gap_length"),
    ("evenly_spaced", dict(n_gaps=0), "n_gaps"),
    ("evenly_spaced", dict(gap_length=0), "gap_length"),
    ("blackout", dict(gap_length=300), "gap_length"),
    ("random_entries", dict(rate=1.0), "rate"),
    ("random_entries", dict(rate=-0.1), "rate"),
    ("continuous_runs", dict(n_markers=-1), "n_markers"),
    ("continuous_runs", dict(gap_length=1000), "gap_length"),
]


@pytest.mark.parametrize("name,kwargs,word", BAD, ids=[f"{n}-{w}-{i}" for i, (n, _, w) in enumerate(BAD)])
def test_bad_arguments_raise(name, kwargs, word):
    with pytest.raises(ValueError, match=word):
        gaps.generate(name, 300, 20, **kwargs)


@pytest.mark.parametrize("T,J", [(0, 5), (10, 0)])
def test_empty_shapes_raise(T, J):
    for name in gaps.PROTOCOLS:
        with pytest.raises(ValueError):
            gaps.generate(name, T, J, **{k: v for k, v in KWARGS[name].items() if k == "rate"})


# --- real gap patterns laid onto complete recordings ----------------------------------------

def test_transplant_keeps_each_markers_runs_and_their_duration():
    src = np.zeros((240, 4), dtype=bool)
    src[:48, 0] = True                      # 0.2 s at 240 Hz, at the trial start
    src[100:148, 1] = True                  # an interior gap
    src[:, 3] = True                        # a dead marker: dropped
    M = gaps.transplant(src, 120, 10, seed=3, rate_ratio=0.5)
    assert M.shape == (120, 10)
    lengths = sorted(b - a for _, a, b in gap_runs(M))
    assert lengths == [24, 24]              # 48 frames at 240 Hz = 24 at 120 Hz
    starts = sorted(a for _, a, _ in gap_runs(M))
    assert starts == [0, 50]                # the trial-start gap stays at the start
    assert M.any(axis=0).sum() == 2


def test_transplant_by_layout_sends_markers_to_the_same_place_on_the_body():
    labels_src = ["LANK", "RANK", "LSHO", "RSHO", "CLAV"]
    labels_dst = ["C7", "L.Shoulder", "R.Shoulder", "L.Ankle", "R.Ankle", "Sacrum"]
    body = {"ANK": 50.0, "SHO": 1400.0, "CLAV": 1450.0, "C7": 1500.0, "Ankle": 60.0,
            "Shoulder": 1420.0, "Sacrum": 950.0}
    side = {"L": -150.0, "R": 150.0}

    def pose(labels):
        P = np.zeros((5, len(labels), 3))
        for j, lab in enumerate(labels):
            part = next(v for k, v in body.items() if k in lab)
            P[:, j] = [side.get(lab[0], 0.0) if lab[0] in "LR" else 0.0, 0.0, part]
        return P + np.arange(5)[:, None, None]

    src = np.zeros((5, 5), dtype=bool)
    src[1:, 0] = src[:2, 2] = True          # LANK and LSHO have gaps
    M = gaps.transplant(src, 5, 6, seed=0, source_layout=gaps.body_layout(pose(labels_src), labels_src),
                        target_layout=gaps.body_layout(pose(labels_dst), labels_dst))
    assert M[1:, labels_dst.index("L.Ankle")].all()
    assert M[:2, labels_dst.index("L.Shoulder")].all() and M.sum() == 4 + 2


def test_transplant_refuses_a_pattern_shorter_than_the_recording():
    with pytest.raises(ValueError, match="cut the target"):
        gaps.transplant(np.ones((10, 2), dtype=bool) & False | np.eye(10, 2, dtype=bool), 20, 3)


def _walk(T=400, J=12, seed=0):
    """Markers drifting at a speed that is lowest around frame 200."""
    rng = np.random.default_rng(seed)
    speed = 1.0 + np.abs(np.arange(T) - 200)[:, None, None] / 50.0
    return np.cumsum(rng.normal(size=(T, J, 3)) * speed, axis=0)


def test_trial_ends_hides_markers_at_both_ends_only():
    mask = gaps.trial_ends(300, 12, n_markers=6, gap_length=40, seed=3)
    hidden = np.flatnonzero(mask.any(axis=0))
    assert len(hidden) == 6 and mask.sum() == 6 * 40
    assert mask[:40].sum() == 3 * 40 and mask[-40:].sum() == 3 * 40 and not mask[40:-40].any()


def test_still_window_sits_where_the_markers_move_least():
    P = _walk()
    mask = gaps.still_window(P, n_markers=5, gap_length=60, seed=1)
    rows = np.flatnonzero(mask.any(axis=1))
    assert mask.any(axis=0).sum() == 5 and len(rows) == 60 and np.ptp(rows) == 59
    assert rows[0] < 200 < rows[-1]                           # the slow stretch
    assert not mask[0].any() and not mask[-1].any()


def test_clustered_gives_every_marker_a_gap_and_never_a_whole_frame():
    P = _walk(J=15)
    for seed in range(3):
        mask = gaps.clustered(P, seed=seed)
        assert mask.any(axis=0).all() and not mask.all(axis=1).any()
        assert np.array_equal(mask, gaps.clustered(P, seed=seed))


def test_grouped_windows_hide_every_marker_in_group_windows():
    P = _walk(J=15)
    mask = gaps.grouped_windows(P, groups=4, windows=2, seed=2)
    assert mask.any(axis=0).all()
    assert np.array_equal(mask, gaps.grouped_windows(P, groups=4, windows=2, seed=2))
