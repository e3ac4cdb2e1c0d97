"""Independent pieces of torch work (the windows of a long recording, ``auto``'s candidates) run
in threads that share torch's intra-op threads out: torch's kernels release the GIL, and one fit's
small products keep a second core mostly idle (bench_long 120 000 frames on 2 cores: 96 s one
window at a time with 2 threads, 52-59 s two at a time with one each)."""
from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import torch

_INSIDE = threading.local()


def thread_map(fn: Callable[[Any], Any], items: Iterable, workers: int | None = None) -> Iterator:
    """``fn(item)`` for every item, yielded in the items' order whatever finishes first.

    ``workers`` at a time (None: ``torch.get_num_threads()``, also the most), each thread on
    ``torch.get_num_threads() // workers`` intra-op threads (restored afterwards); with one worker,
    one item or inside another ``thread_map``, in this thread. The caller's warning filters are
    restored afterwards: ``warnings.catch_warnings`` in two threads at once can leave them changed.
    """
    items = list(items)
    threads = torch.get_num_threads()
    workers = min(workers or threads, threads, len(items))
    if workers <= 1 or getattr(_INSIDE, "active", False):
        yield from map(fn, items)
        return

    def run(item):
        _INSIDE.active = True
        return fn(item)

    torch.set_num_threads(threads // workers)
    try:
        with warnings.catch_warnings(), ThreadPoolExecutor(workers, "torchfill") as pool:
            yield from pool.map(run, items)
    finally:
        torch.set_num_threads(threads)
