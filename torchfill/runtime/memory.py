"""The process's free heap memory handed back to the system between the stages of a long fill.

A long recording's fill allocates and frees many full-length temporaries (in numpy and in torch,
from several worker threads). glibc's ``malloc`` keeps what was freed in its arenas for reuse, and
a later large request often cannot reuse those holes, so the resident size grows by the freed
memory over the windows: at 120 000 frames x 41 markers the default's peak RSS was 2.4-2.6 GB with
1.3 GB of live allocations at its highest. :func:`trim_heap` (``malloc_trim``) returns the free
pages at the points where a stage's temporaries are gone. Elsewhere than glibc it does nothing.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable


@functools.lru_cache(maxsize=1)
def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    try:
        fn = ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        return None
    if fn is not None:
        fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
    return fn


#: Arrays of at least this many bytes (a (T, J, 3) float64 of 4000 frames x 41 markers) make a
#: stage worth trimming after: below it the pages given back cost more time to fault in again
#: than they save (3 000 x 41 frames: 0.4 s of 16 s for -190 MB of peak RSS).
LARGE_BYTES = 4 << 20


def trim_heap(nbytes: int | None = None) -> None:
    """Return the heap's free pages to the system (a few milliseconds; a no-op without glibc);
    with ``nbytes``, only when the stage's arrays are that large (see ``LARGE_BYTES``)."""
    fn = _malloc_trim()
    if fn is not None and (nbytes is None or nbytes >= LARGE_BYTES):
        fn(0)
