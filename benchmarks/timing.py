"""Timing of one call: wall seconds, CPU seconds (all threads of the process: robust to a
loaded machine) and the peak resident memory above the start (sampled every 10 ms)."""
from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass


def rss_mb() -> float:
    """This process's resident memory now, MB (0 where /proc is absent)."""
    try:
        with open("/proc/self/statm") as handle:
            pages = int(handle.read().split()[1])
    except OSError:
        return 0.0
    import os
    return pages * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


@dataclass
class Timing:
    wall: float = 0.0
    cpu: float = 0.0
    peak_mb: float = 0.0


@contextmanager
def measure(sample_s: float = 0.01):
    """``with measure() as t: ...`` fills ``t.wall``, ``t.cpu``, ``t.peak_mb``."""
    out, stop = Timing(), threading.Event()
    base, peak = rss_mb(), [0.0]

    def watch():
        while not stop.wait(sample_s):
            peak[0] = max(peak[0], rss_mb())

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        yield out
    finally:
        out.wall, out.cpu = time.perf_counter() - wall, time.process_time() - cpu
        stop.set()
        watcher.join()
        out.peak_mb = max(peak[0], rss_mb()) - base
