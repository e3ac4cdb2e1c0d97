"""torchfill.runtime: threads that share torch's threads out, the cache cleared per window."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchfill


def _threads(n):
    """torch's thread count set to ``n`` for a test, restored afterwards."""
    import contextlib

    @contextlib.contextmanager
    def scope():
        before = torch.get_num_threads()
        torch.set_num_threads(n)
        try:
            yield
        finally:
            torch.set_num_threads(before)
    return scope()


def test_thread_map_keeps_order_and_shares_threads_per_worker_only():
    import threading
    import time

    from torchfill.runtime.threads import thread_map
    from torchfill.runtime.threads import _omp_set_num_threads

    if _omp_set_num_threads() is None:
        pytest.skip("torch without a reachable OpenMP runtime: workers keep their count")
    seen = []

    def work(k):
        time.sleep(0.01 * (5 - k))                       # the later items finish first
        seen.append((threading.current_thread().name, torch.get_num_threads()))
        if threading.current_thread().name.startswith("torchfill"):
            inner = list(thread_map(lambda x: threading.current_thread().name, [0, 1]))
            assert set(inner) == {threading.current_thread().name}   # nested: serial, here
        return k * k

    with _threads(4):
        assert list(thread_map(work, range(5), workers=2)) == [0, 1, 4, 9, 16]
        assert {n for _, n in seen} == {2}                # 4 threads // 2 workers, in the workers
        assert torch.get_num_threads() == 4               # never changed here
        fresh = []
        t = threading.Thread(target=lambda: fresh.append(torch.get_num_threads()))
        t.start(), t.join()
        assert fresh == [4]                               # nor for threads started later
        assert len({name for name, _ in seen}) == 2
        assert list(thread_map(work, range(3), workers=1)) == [0, 1, 4]    # serial: all threads; a nested call
        # in this thread may still use workers (a one-window fill keeps its candidates side by side)
        assert seen[-1] == (threading.current_thread().name, 4)


def test_after_runs_the_work_next_in_the_first_ones_lane_and_passes_on_its_error():
    import threading

    from torchfill.runtime.threads import Lanes, after

    gate, order = threading.Event(), []

    def name(tag):
        order.append((tag, threading.current_thread().name))
        return tag

    with _threads(2), Lanes(2) as lanes:
        first = lanes.submit(lambda: (gate.wait(5), name("first"))[1])
        second = after(first, lanes, name, "second")
        failing = after(first, lanes, lambda: 1 / 0)
        queued = [lanes.submit(name, "queued") for _ in range(2)]      # the other lane's work
        assert not second.done()
        gate.set()
        assert second.result(5) == "second"
        with pytest.raises(ZeroDivisionError):
            failing.result(5)
        [q.result(5) for q in queued]
        assert after(first, lanes, name, "done").result(5) == "done"   # first done: a free lane
    lane = dict(order)
    assert lane["second"] == lane["first"]          # next in the lane that ran the first
    assert order.index(("second", lane["first"])) == order.index(("first", lane["first"])) + 1
    closed = after(first, lanes, name, "late")      # the lanes closed meanwhile
    with pytest.raises(RuntimeError):
        closed.result(5)


def test_thread_map_starts_the_costliest_first_and_yields_in_order():
    import threading
    import time

    from torchfill.runtime.threads import thread_map

    started, lock = [], threading.Lock()

    def work(k):
        with lock:
            started.append(k)
        time.sleep(0.05)                                  # both workers take one before more start
        return -k

    cost = {0: 1.0, 1: 5.0, 2: 0.5, 3: 9.0}.__getitem__
    with _threads(2):
        assert list(thread_map(work, range(4), workers=1, cost=cost)) == [0, -1, -2, -3]
        assert started == [0, 1, 2, 3]                    # serial: in the items' order
        started.clear()
        assert list(thread_map(work, range(4), workers=2, cost=cost)) == [0, -1, -2, -3]
    assert started[:2] in ([3, 1], [1, 3]) and sorted(started[2:]) == [0, 2]   # 9 and 5 first


def test_windowed_fill_in_threads_leaves_other_threads_thread_count_alone():
    """A watcher thread of the caller's program samples torch's thread count (its own, and that of
    threads it starts) all through a fill whose windows run in two worker threads: it never changes (the library leaves global torch
    state alone: threads, default dtype, seeds)."""
    import threading

    import numpy as np

    import torchfill
    from torchfill import gaps

    rng = np.random.default_rng(0)
    T, J = 1200, 10
    t = np.arange(T)[:, None, None] / 100.0
    X = 100 * np.sin(t * rng.uniform(0.5, 2, (1, J, 3)) + rng.uniform(0, 6, (1, J, 3)))
    mask = gaps.multi_gap(T, J, n_markers=4, gap_length=30, max_gaps=4, seed=0)
    given = np.where(mask[..., None], np.nan, X)
    seeds = torch.initial_seed(), torch.get_default_dtype()
    with _threads(2):
        stop, counts = threading.Event(), []

        def sample():
            counts.append(torch.get_num_threads())

        def watch():                 # the count a thread of the program starts torch work with
            while not stop.is_set():
                fresh = threading.Thread(target=sample)
                fresh.start(), fresh.join()
                sample()
                stop.wait(0.001)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            out = torchfill.fill(given, "svt", window=200, workers=2, constraints=False)
        finally:
            stop.set()
            watcher.join()
    assert len(counts) > 10 and set(counts) == {2}, sorted(set(counts))
    assert (torch.initial_seed(), torch.get_default_dtype()) == seeds
    assert np.isfinite(out[mask]).all()


def test_memo_keeps_a_result_by_the_inputs_content():
    from torchfill.runtime.cache import Memo
    memo, calls = Memo(entries=2), []

    def f(x):
        calls.append(1)
        return x * 2
    x = torch.arange(6.0)
    assert torch.equal(memo(lambda: f(x), x, "a"), x * 2)
    assert torch.equal(memo(lambda: f(x.clone()), x.clone(), "a"), x * 2)   # equal content: kept
    assert len(calls) == 1
    memo(lambda: f(x), x, "b")                                              # another argument
    memo(lambda: f(x + 1), x + 1, "a")                                      # other content
    memo(lambda: f(x), x.to(torch.float64), "a")                            # other dtype
    assert len(calls) == 4
    memo(lambda: f(x), x, "a")                            # pushed out by the last two entries
    assert len(calls) == 5


def test_memo_keeps_at_most_its_byte_budget():
    from torchfill.runtime.cache import Memo
    memo = Memo(entries=10, max_bytes=3 * 80)                 # three 10-double results
    for k in range(5):
        memo(lambda: torch.full((10,), float(k), dtype=torch.float64), k)
    assert len(memo._kept) == 3 and memo._bytes == 3 * 80  # the oldest two pushed out
    calls = []
    memo(lambda: calls.append(1) or torch.zeros(10, dtype=torch.float64), 4)   # still kept
    assert not calls
    memo.clear()
    assert memo._bytes == 0 and not memo._kept


def test_a_windowed_fill_leaves_no_kept_results_behind(recording):
    """A long recording's windows are other data each: what one window kept for a repeat
    (``runtime.cache`` memos: rigid's reconstructions, pca's training eigenspaces among them) is
    dropped when it is done, so no window's results stay in memory beside the next one's."""
    from torchfill.runtime import cache
    from torchfill.solvers import pca, rigid

    assert {rigid._KEPT, pca._KEPT} <= set(cache._ALL)
    X = torchfill.read(recording("HDM_bd_01-02_01_120.c3d")).points[:1200].copy()
    X[200:300, 3] = np.nan
    X[700:780, 9] = np.nan
    torchfill.fill(X, "pca_gloersen", window=None)     # one window: results kept
    assert any(m._kept for m in cache._ALL) and rigid._KEPT._kept
    torchfill.fill(X, "pca_gloersen", window=600, constraints=False)   # windows: dropped
    assert not any(m._kept for m in cache._ALL)     # rigid's and pca's memos among them
