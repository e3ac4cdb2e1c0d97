"""Independent pieces of torch work (the windows of a long recording, ``auto``'s candidates) run
in threads that share torch's intra-op threads out: torch's kernels release the GIL, and one fit's
small products keep a second core mostly idle (bench_long 120 000 frames on 2 cores: 96 s one
window at a time with 2 threads, 52-59 s two at a time with one each).

The share is set **per worker thread** (OpenMP's thread count is a per-thread setting), never with
``torch.set_num_threads``: that also changes the count every thread started later begins with,
which the rest of the caller's program would see while a fill runs. Where no OpenMP runtime can be
reached (a torch built without it), the workers run with the count they inherit.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import os
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import torch

_INSIDE = threading.local()


def _find(symbol: str, candidates: list) -> Callable[[int], Any] | None:
    for path in candidates:
        try:
            fn = getattr(ctypes.CDLL(path), symbol)
        except (OSError, AttributeError, TypeError):
            continue
        fn.argtypes = [ctypes.c_int]
        return fn
    return None


@functools.lru_cache(maxsize=1)
def _omp_set_num_threads() -> Callable[[int], Any] | None:
    """``omp_set_num_threads`` of the OpenMP runtime torch runs on (it sets the calling thread's
    team size only), or None."""
    lib = os.path.join(os.path.dirname(torch.__file__), "lib")
    candidates = [None]                                   # already in the process's global scope
    candidates += sorted(glob.glob(os.path.join(lib, "libgomp*")) + glob.glob(os.path.join(lib, "libiomp*")))
    candidates += [ctypes.util.find_library(n) for n in ("gomp", "iomp5", "omp")]
    return _find("omp_set_num_threads", candidates)


@functools.lru_cache(maxsize=1)
def _mkl_set_num_threads_local() -> Callable[[int], Any] | None:
    """MKL's thread-local thread count (what ``torch.set_num_threads`` sets for MKL), or None."""
    lib = os.path.join(os.path.dirname(torch.__file__), "lib")
    return _find("MKL_Set_Num_Threads_Local", [None, *sorted(glob.glob(os.path.join(lib, "libtorch_cpu*")))])


@contextmanager
def serial():
    """Inside, :func:`thread_map` runs in the calling thread, as it does inside another
    ``thread_map``'s worker (a window in a worker process fits as a window thread does)."""
    before = getattr(_INSIDE, "active", False)
    _INSIDE.active = True
    try:
        yield
    finally:
        _INSIDE.active = before


class Lanes:
    """Worker threads set up as :func:`thread_map`'s (each on ``share`` intra-op threads, set in
    that thread only), kept open across several batches of work: a long item runs in one lane
    while the next batches run in the others. ``submit(fn, *args)`` returns a
    :class:`~concurrent.futures.Future`; items start in submission order. Where
    :func:`thread_map` would run in the calling thread (one worker, or inside another
    ``thread_map`` or :func:`serial`), ``parallel`` is False and no threads start (the caller
    runs its work itself). Leaving the block cancels what has not started and waits for the
    rest; the caller's warning filters are restored."""

    def __init__(self, workers: int | None = None) -> None:
        threads = torch.get_num_threads()
        self.workers = min(workers or threads, threads)
        self.parallel = self.workers > 1 and not getattr(_INSIDE, "active", False)
        self.share = max(1, threads // max(self.workers, 1))
        self._pool: ThreadPoolExecutor | None = None
        self._filters = warnings.catch_warnings()

    def __enter__(self) -> "Lanes":
        if self.parallel:
            self._filters.__enter__()
            self._pool = ThreadPoolExecutor(self.workers, "torchfill")
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            self._filters.__exit__(*exc)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """``fn(*args)`` in the next free lane (inside the block, where ``parallel``)."""
        if self._pool is None:
            raise RuntimeError("Lanes.submit: no lanes open (outside the block, or not parallel)")
        return self._pool.submit(_in_lane, self.share, fn, args)


def after(first: Future, lanes: Lanes, fn: Callable[..., Any], *args: Any) -> Future:
    """A :class:`~concurrent.futures.Future` of ``fn(*args)`` run as soon as ``first`` is done:
    next in the lane that ran ``first`` (ahead of what is queued), or in the next free lane of
    ``lanes`` where ``first`` was done already."""
    out: Future = Future()

    def run() -> None:
        try:
            out.set_result(fn(*args))
        except BaseException as err:          # noqa: BLE001 -- the future carries it
            out.set_exception(err)

    def relay(done: Future) -> None:
        err = done.exception()
        out.set_exception(err) if err is not None else out.set_result(done.result())

    def go(_: Future) -> None:
        if getattr(_INSIDE, "active", False):  # the lane's own thread, its share already set
            run()
            return
        try:
            lanes.submit(fn, *args).add_done_callback(relay)
        except RuntimeError as err:           # the lanes closed meanwhile (the fill failed)
            out.set_exception(err)
    first.add_done_callback(go)
    return out


def _in_lane(share: int, fn: Callable[..., Any], args: tuple) -> Any:
    _INSIDE.active = True
    # torch's lazy per-thread start first (it would reset them to torch's own count), through
    # torch's own function: a caller's stand-in for torch.get_num_threads would skip it
    torch._C.get_num_threads()
    for set_threads in (_omp_set_num_threads(), _mkl_set_num_threads_local()):
        if set_threads is not None:  # this thread's OpenMP team and MKL count only
            set_threads(share)
    return fn(*args)


def thread_map(fn: Callable[[Any], Any], items: Iterable, workers: int | None = None,
               cost: Callable[[Any], float] | None = None, share: int | None = None) -> Iterator:
    """``fn(item)`` for every item, yielded in the items' order whatever finishes first.

    ``cost``: the item's expected time; the costliest start first (longest-processing-time
    order), so a long item queued last does not run alone after the others have finished
    (``auto``'s candidates on bench_long's 3 000 frames: ``tucker_tnn``, the longest fit, was the
    last of nine to start).

    ``workers`` at a time (None: ``torch.get_num_threads()``, also the most), each worker thread
    on ``share`` (default: ``torch.get_num_threads() // workers``) intra-op threads, set in that
    thread only (no process-wide change: other threads of the program keep their count); with
    one worker, one item or inside another ``thread_map`` (or :func:`serial`), in this thread. The caller's warning filters are
    restored afterwards: ``warnings.catch_warnings`` in two threads at once can leave them changed.
    """
    items = list(items)
    threads = torch.get_num_threads()
    workers = min(workers or threads, threads, len(items))
    if workers <= 1 or getattr(_INSIDE, "active", False):
        yield from map(fn, items)
        return
    share = share or max(1, threads // workers)
    order = range(len(items)) if cost is None else \
        sorted(range(len(items)), key=lambda i: -cost(items[i]))
    with warnings.catch_warnings(), ThreadPoolExecutor(workers, "torchfill") as pool:
        futures = {i: pool.submit(_in_lane, share, fn, (items[i],)) for i in order}
        for i in range(len(items)):
            yield futures.pop(i).result()
