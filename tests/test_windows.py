"""Windowed fills: the plan covers the recording with overlaps that hold every gap whole, the blend
is a convex combination (a local method gives exactly its unwindowed fill), observed samples stay
bit-for-bit, and on a real recording a windowed low-rank fill stays close to the whole fill."""
from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
import torch

import torchfill
from torchfill import gaps, metrics, windows
from torchfill.metrics import gap_runs


def _long_walk(T=3000, J=6, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 120
    phase = rng.uniform(0, 2 * np.pi, size=(1, J, 3))
    return 800 + 300 * np.sin(0.7 * t + phase) + 40 * np.cos(3.1 * t + 2 * phase)


@pytest.mark.parametrize("T, gap, window", [(3000, 40, 300), (5000, 150, 600), (1000, 20, 2000),
                                            (2500, 300, 1000)])
def test_plan_covers_and_holds_every_gap_whole(T, gap, window):
    mask = gaps.multi_gap(T, 8, n_markers=6, gap_length=gap, max_gaps=5, seed=T)
    plan = windows.plan(mask, window)
    starts, stops = zip(*plan.windows)
    assert starts[0] == 0 and stops[-1] == T and list(starts) == sorted(starts)
    assert all(b - a == plan.length for a, b in plan.windows)
    assert all(stops[k] - starts[k + 1] >= plan.overlap for k in range(len(starts) - 1))
    for j, a, b in gap_runs(mask):   # some window holds the gap and one frame either side
        assert any(s <= max(a - 1, 0) and min(b + 1, T) <= e for s, e in plan.windows)
    if window >= T:
        assert plan.windows == ((0, T),)


def test_blend_weights_sum_to_one_on_every_gap():
    T = 4000
    mask = gaps.multi_gap(T, 5, n_markers=5, gap_length=120, max_gaps=5, seed=3)
    plan = windows.plan(mask, 800)
    total = np.zeros(mask.shape)
    for k, (a, b) in enumerate(plan.windows):
        total[a:b] += windows.weight(plan, k, mask[a:b], T)
    assert len(plan.windows) > 3
    assert (total[mask] > 0).all()   # no gap is cut by every window that reaches it


def test_windowed_linear_fill_equals_the_whole_fill():
    X = _long_walk()
    mask = gaps.multi_gap(*X.shape[:2], n_markers=5, gap_length=60, max_gaps=5, seed=2)
    given = np.where(mask[..., None], np.nan, X)
    whole = torchfill.fill(given, "linear", window=None)
    windowed = torchfill.fill(given, "linear", window=400)
    np.testing.assert_allclose(windowed, whole, rtol=0, atol=1e-9)
    assert np.array_equal(windowed[~mask], X[~mask])


def test_windows_in_threads_blend_in_order_whatever_finishes_first(monkeypatch):
    X = _long_walk()
    mask = gaps.multi_gap(*X.shape[:2], n_markers=5, gap_length=60, max_gaps=5, seed=2)
    given = np.where(mask[..., None], np.nan, X)
    plan = windows.plan(mask, 400)
    assert len(plan.windows) > 3
    order = []

    def solve(a, b):                                   # later windows finish first
        time.sleep(0.02 * (len(plan.windows) - [w[0] for w in plan.windows].index(a)))
        order.append(a)
        return torchfill.fill(given[a:b], "linear", window=None)

    missing = torch.from_numpy(mask)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 4)      # threads to share out
    monkeypatch.setattr(torch, "set_num_threads", lambda n: None)
    threaded = windows.blend(plan, missing, lambda a, b: torch.from_numpy(solve(a, b)), workers=3)
    assert order != sorted(order)                                   # they did finish out of order
    serial = windows.blend(plan, missing, lambda a, b: torch.from_numpy(solve(a, b)), workers=1)
    assert torch.equal(threaded, serial)


def test_blend_emits_each_frame_once_in_order_as_soon_as_final():
    """A long recording's blend is handed on in pieces, never whole: each piece ends where the
    next window starts (no later window reaches it), and together they are the whole blend's
    bits."""
    X = _long_walk()
    mask = gaps.multi_gap(*X.shape[:2], n_markers=5, gap_length=60, max_gaps=5, seed=2)
    given = np.where(mask[..., None], np.nan, X)
    plan = windows.plan(mask, 400)
    missing = torch.from_numpy(mask)
    solved = []

    def solve(a, b):
        solved.append(a)
        return torch.from_numpy(torchfill.fill(given[a:b], "linear", window=None))
    pieces = []

    def emit(a, b, values):               # right after a window: up to the next one's start
        k = len(solved)
        assert b == (plan.windows[k][0] if k < len(plan.windows) else len(X))
        pieces.append((a, b, values.clone()))
    assert windows.blend(plan, missing, solve, emit=emit) is None
    whole = windows.blend(plan, missing, solve)
    starts = [w[0] for w in plan.windows[1:]]
    assert [p[:2] for p in pieces] == list(zip([0] + starts, starts + [len(X)]))
    joined = torch.cat([p[2] for p in pieces])
    assert torch.equal(joined.nan_to_num(-1.0), whole.nan_to_num(-1.0))
    assert torch.equal(joined.isnan(), whole.isnan())


def test_default_fill_in_window_threads_is_as_accurate_as_the_serial_fill(recording):
    truth = torchfill.read(recording("cmu_85_02.c3d")).points             # 810 frames
    mask = gaps.multi_gap(*truth.shape[:2], n_markers=10, gap_length=20, max_gaps=2, seed=0)
    given = np.where(mask[..., None], np.nan, truth)
    assert len(windows.plan(mask, 120).windows) == 4
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        serial = torchfill.fill(given, window=120, workers=1)
        threaded = torchfill.fill(given, window=120, workers=2)
        again = torchfill.fill(given, window=120, workers=2)
    finally:
        torch.set_num_threads(before)
    assert torch.get_num_threads() == before
    assert np.array_equal(threaded, again, equal_nan=True)                  # deterministic
    assert np.array_equal(threaded[~mask], truth[~mask])
    # one thread per window instead of two rounds float32 sums differently, and the hold-out may
    # then keep another iterate: a few samples move by mm, the accuracy does not
    err, err_serial = (metrics.rmse_missing(f, truth, mask) for f in (threaded, serial))
    assert abs(err - err_serial) <= 0.1 * err_serial, (err, err_serial)


def test_windows_in_threads_leave_the_warning_filters_as_they_were(recording, monkeypatch):
    """auto silences its candidates' warnings in every window; interleaved, those contexts could
    leave ``ignore`` installed for good."""
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)     # two window threads, any machine
    monkeypatch.setattr(torch, "set_num_threads", lambda n: None)
    truth = torchfill.read(recording("cmu_85_02.c3d")).points[:, :12]
    mask = gaps.multi_gap(*truth.shape[:2], n_markers=4, gap_length=20, max_gaps=2, seed=1)
    given = np.where(mask[..., None], np.nan, truth)
    before = list(warnings.filters)
    torchfill.fill(given, "auto", candidates=["pchip", "svt"], window=120, workers=2,
                   constraints=False)
    assert warnings.filters == before


def test_window_is_validated():
    with pytest.raises(ValueError, match="window expected"):
        torchfill.fill(_long_walk(T=50), "linear", window=1)
    with pytest.raises(ValueError, match="workers expected"):
        torchfill.fill(_long_walk(T=50), "linear", workers=0)


def test_windowed_low_rank_fill_of_a_real_recording(recording):
    truth = torchfill.read(recording("cmu_02_01.c3d")).points            # 343 frames, 41 markers
    mask = gaps.multi_gap(*truth.shape[:2], n_markers=10, gap_length=30, max_gaps=3, seed=1)
    given = np.where(mask[..., None], np.nan, truth)
    windowed = torchfill.fill(given, "svt", window=300)                   # two windows
    assert len(windows.plan(mask, 300).windows) == 2
    assert np.array_equal(windowed[~mask], truth[~mask]) and np.isfinite(windowed).all()
    err = metrics.rmse_missing(windowed, truth, mask)
    whole = metrics.rmse_missing(torchfill.fill(given, "svt", window=None), truth, mask)
    linear = metrics.rmse_missing(torchfill.fill(given, "linear"), truth, mask)
    assert err < 0.5 * linear and err < 1.25 * whole    # mm: measured 7.4 vs 7.2 whole, 20.4 linear


def test_cli_window_reaches_fill(tmp_path):
    from torchfill.cli import main

    X = _long_walk(T=600)
    mask = gaps.multi_gap(*X.shape[:2], n_markers=4, gap_length=40, max_gaps=3, seed=3)
    given = np.where(mask[..., None], np.nan, X)
    src = tmp_path / "walk.npz"
    np.savez(src, points=given, labels=np.array([f"M{j}" for j in range(X.shape[1])]), rate=120.0,
             units="mm")
    for flag, window in (("300", 300), ("0", None)):
        out = tmp_path / f"out{flag}.npz"
        assert main(["fill", str(src), "-o", str(out), "-m", "svt", "-p", "max_iter=30", "-q",
                     "--window", flag]) == 0
        expected = torchfill.fill(given, "svt", window=window, max_iter=30)
        assert np.array_equal(np.load(out)["points"], expected)
    assert not np.array_equal(np.load(tmp_path / "out300.npz")["points"],
                              np.load(tmp_path / "out0.npz")["points"])   # 3 windows vs 1
    assert main(["fill", str(src), "-o", str(tmp_path / "x.npz"), "--window", "-5"]) == 2


def test_progress_names_the_window(walk):
    X = walk(T=900, J=6)
    mask = gaps.multi_gap(900, 6, n_markers=3, gap_length=30, max_gaps=2, seed=0)
    given = np.where(mask[..., None], np.nan, X)
    seen = []
    torchfill.fill(given, "svt", window=300, workers=1, progress=seen.append)
    n = len(windows.plan(mask, 300).windows)
    assert n > 2 and {d["windows"] for d in seen} == {n}
    assert {d["window"] for d in seen} == set(range(1, n + 1))
    assert list(seen[0])[:2] == ["window", "windows"] and "iter" in seen[0]


def _spy_on_workers(monkeypatch) -> list:
    """The worker counts of the process pools the windows start (a list that grows)."""
    launched = []

    class Spy(windows.Processes):
        def launch(self):
            before = len(self.started)
            super().launch()
            if len(self.started) > before:
                launched.append(len(self.started))
    monkeypatch.setattr(windows, "Processes", Spy)
    monkeypatch.setattr(windows.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)      # two lanes on any machine
    monkeypatch.setattr(torch, "set_num_threads", lambda n: None)
    return launched


def test_later_windows_in_worker_processes_fill_bit_for_bit_as_in_threads(recording, monkeypatch):
    """The default on a real recording of four windows: the three later ones in two worker
    processes (started at once here) give the threads' fill and error estimate bit for bit, and
    their progress comes back."""
    truth = torchfill.read(recording("cmu_85_02.c3d")).points             # 810 frames
    mask = gaps.multi_gap(*truth.shape[:2], n_markers=10, gap_length=20, max_gaps=2, seed=0)
    given = np.where(mask[..., None], np.nan, truth)
    assert len(windows.plan(mask, 300).windows) == 4
    launched = _spy_on_workers(monkeypatch)
    monkeypatch.setattr(windows, "LAUNCH_AFTER", 0.0)
    seen = []
    filled, std = torchfill.fill(given, window=300, return_std=True, progress=seen.append)
    assert launched == [2]
    monkeypatch.setattr(windows, "PROCESS_MIN_LATER", 10**6)               # threads instead
    threaded, std_threaded = torchfill.fill(given, window=300, return_std=True)
    assert launched == [2]
    assert np.array_equal(filled, threaded, equal_nan=True)
    assert np.array_equal(std, std_threaded, equal_nan=True)
    assert np.array_equal(filled[~mask], truth[~mask]) and np.isfinite(filled).all()
    assert {d["window"] for d in seen} == {1, 2, 3, 4} and {d["windows"] for d in seen} == {4}


def test_worker_processes_hand_back_warnings_and_errors(walk, monkeypatch):
    """What a window gives besides its fill crosses back from its worker: a warning is given
    here (under the caller's filters), an error raised here."""
    from torchfill.solvers import NotConvergedWarning

    X = walk(T=1200, J=6)
    mask = gaps.multi_gap(1200, 6, n_markers=3, gap_length=30, max_gaps=2, seed=0)
    given = np.where(mask[..., None], np.nan, X)
    launched = _spy_on_workers(monkeypatch)
    monkeypatch.setattr(windows, "LAUNCH_AFTER", 0.0)
    with pytest.warns(NotConvergedWarning) as caught:
        filled = torchfill.fill(given, "svt", window=300, workers=2, params={"max_iter": 3})
    assert launched == [2] and len(caught) >= 3          # the first window's and the workers'
    monkeypatch.setattr(windows, "PROCESS_MIN_LATER", 10**6)
    with pytest.warns(NotConvergedWarning):
        threaded = torchfill.fill(given, "svt", window=300, workers=2, params={"max_iter": 3})
    assert np.array_equal(filled, threaded)
    job = windows.Job("rigid", {}, {}, 1, torch.arange(6))                   # 2-D: refused
    X2 = torch.from_numpy(given[:300, :, :2].copy())
    err, _ = windows.fit_remote(job, X2, ~torch.isfinite(X2).all(dim=2), (0, 300), 1, False)
    assert isinstance(err, ValueError) and "rigid" in str(err)


def test_short_recordings_and_fast_windows_stay_in_this_process(walk, monkeypatch):
    """Worker processes cost a second or two each to start: none for one or two windows, nor when
    the first window ends before ``LAUNCH_AFTER``."""
    launched = _spy_on_workers(monkeypatch)
    X = walk(T=1200, J=6)
    mask = gaps.multi_gap(1200, 6, n_markers=3, gap_length=30, max_gaps=2, seed=0)
    given = np.where(mask[..., None], np.nan, X)
    assert len(windows.plan(mask, 700).windows) == 2 and len(windows.plan(mask, 300).windows) > 3
    monkeypatch.setattr(windows, "LAUNCH_AFTER", 0.0)
    torchfill.fill(given, "linear", window=700, workers=2)
    monkeypatch.setattr(windows, "LAUNCH_AFTER", 60.0)
    torchfill.fill(given, "linear", window=300, workers=2)
    assert launched == []
