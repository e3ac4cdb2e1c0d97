"""Progress of one fill: percent and time left over the whole fill (windows x iterations, or
``auto``'s candidate fits), shown as a tqdm bar on a terminal and as one summary line elsewhere.

``fill(..., progress=True)`` shows it; ``progress=callable`` receives every record as a dict
(``window``, ``windows``, ``max_iter`` and the solver's own record: ``iter``, ``delta``, ...;
``auto`` reports ``fit``/``fits`` and ``refit``/``refits`` as its candidates finish);
``progress=False`` (the default) shows nothing. tqdm is imported only when a bar is shown.

How the fraction is estimated (the solvers stop on their own rule, so the iterations a fit will
take are not known in advance): each window is one equal share of the fill; inside a window an
iterative solver's share grows as ``iter / expected`` -- ``expected`` is its ``max_iter`` until a
window has finished, then 1.25x the iterations the finished windows took -- and jumps to whole
when the window ends; ``auto``'s share grows with its finished hold-out fits (to 60 %) and refits
(to 95 %). The post-step (:mod:`torchfill.constraints`) is the last tenth of the whole. The time
left is tqdm's: the remaining share at the rate so far, so it errs long while the first window of
an iterative method runs. A step that reports nothing for a second (one long candidate fit) does
not freeze the bar: it creeps towards the end of the stage under way (a fiftieth of the distance
left, at least one unit, every ``TICK`` seconds) and never reaches it, so a record always moves it
on.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable

#: Seconds before the bar appears: fills shorter than this show nothing on a terminal
#: (the environment variable ``TORCHFILL_PROGRESS_DELAY`` overrides it).
DELAY = 2.0
#: Share of the whole fill given to the post-step after the solver.
POST_SHARE = 0.1
#: Where ``auto``'s stages lie inside its window's share: (start, end).
STAGES = {"fit": (0.0, 0.6), "refit": (0.6, 0.95)}
#: Resolution of the bar (units per whole fill).
UNITS = 1000
#: Seconds between the bar's own moves while no record comes (see the module notes).
TICK = 0.5


def make(progress, *, windows: int, method: str):
    """The progress object ``fill()`` talks to: ``progress`` is False/None (nothing), True (a bar
    on a terminal, one summary line otherwise) or a callable that receives the records."""
    if progress is None or progress is False:
        return Silent()
    if progress is True:
        return Bar(windows, method)
    if callable(progress):
        return Forward(progress)
    raise ValueError(f"progress expected True, False or a callable, found {progress!r}")


class Silent:
    """No progress: every call does nothing."""

    def update(self, record: dict) -> None:
        pass

    def window_done(self, window: int, n_iter: int) -> None:
        pass

    def post_step(self) -> None:
        pass

    def close(self, summary: str | None = None) -> None:
        pass


class Forward(Silent):
    """A user's callable: it receives every record as it is."""

    def __init__(self, callback: Callable[[dict], None]):
        self.callback = callback

    def update(self, record: dict) -> None:
        self.callback(record)


class Bar(Silent):
    """The whole fill as one bar (stderr is a terminal) or one summary line (it is not)."""

    def __init__(self, windows: int, method: str, file=None, delay: float | None = None):
        self.file = sys.stderr if file is None else file
        self.windows = max(int(windows), 1)
        self.method = method
        self.share = (1.0 - POST_SHARE) / self.windows
        self.done: dict[int, float] = {}          # window -> fraction of its share
        self.finished: list[int] = []             # iterations the finished windows took
        self.lock = threading.Lock()
        self.start = time.perf_counter()
        self.post = 0.0
        self.postfix = ""
        if delay is None:
            delay = float(os.environ.get("TORCHFILL_PROGRESS_DELAY", DELAY))
        self.bar = None
        self.crept = 0.0                          # where the creep has taken the bar
        self.ceiling = self.share                 # the end of the stage under way
        self.last = time.perf_counter()           # when a record last moved the bar
        self.stop = threading.Event()
        if _isatty(self.file):
            from tqdm import tqdm
            cols, rows = _size(self.file)       # a terminal of unknown size (0 x 0): 80 x 20
            self.bar = tqdm(total=UNITS, file=self.file, delay=delay, leave=False, desc=method,
                            dynamic_ncols=cols > 0, ncols=None if cols > 0 else 80,
                            nrows=None if rows > 0 else 20, mininterval=0.2,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                                       "{elapsed}<{remaining}{postfix}")
            threading.Thread(target=self._tick, daemon=True, name="torchfill-progress").start()

    def fraction(self) -> float:
        return min(1.0, sum(self.done.values()) * self.share + self.post)

    def _tick(self) -> None:
        """Creep while no record comes (see the module notes)."""
        while not self.stop.wait(TICK):
            with self.lock:
                if time.perf_counter() - self.last < 1.0:
                    continue
                now = max(self.fraction(), self.crept)
                room = self.ceiling - 1.0 / UNITS - now
                if room > 0:
                    self.crept = now + min(room, max(1.0 / UNITS, room / 50))
                self._show()
                if self.bar is not None:
                    self.bar.refresh()

    def update(self, record: dict) -> None:
        k = int(record.get("window", 1))
        with self.lock:
            part = _window_part(record, self._expected(record))
            self.done[k] = max(self.done.get(k, 0.0), part)
            self.postfix = _postfix(record, self.windows)
            self.ceiling = (sum(self.done.values()) - self.done[k] + _stage_end(record)) * self.share
            self.last = time.perf_counter()
            self._show()

    def window_done(self, window: int, n_iter: int) -> None:
        with self.lock:
            self.done[window] = 1.0
            self.finished.append(int(n_iter))
            self.ceiling = min(1.0 - POST_SHARE, (sum(self.done.values()) + 1) * self.share)
            self.last = time.perf_counter()
            self._show()

    def post_step(self) -> None:
        with self.lock:
            self.done = {k: 1.0 for k in range(1, self.windows + 1)}
            self.postfix = "constraints"
            self.ceiling, self.last = 1.0, time.perf_counter()
            self._show()

    def close(self, summary: str | None = None) -> None:
        seconds = time.perf_counter() - self.start
        self.stop.set()
        if self.bar is not None:
            self.bar.close()
        elif summary:
            print(f"torchfill: {summary} in {seconds:.1f} s", file=self.file, flush=True)

    def _expected(self, record: dict) -> float:
        cap = float(record.get("max_iter") or 1)
        if self.finished:
            return min(cap, 1.25 * sum(self.finished) / len(self.finished))
        return cap

    def _show(self) -> None:
        if self.bar is None:
            return
        n = int(UNITS * max(self.fraction(), self.crept))
        if n > self.bar.n:
            self.bar.set_postfix_str(self.postfix, refresh=False)
            self.bar.update(n - self.bar.n)


def _window_part(record: dict, expected: float) -> float:
    """The fraction of its window a record says is done (see the module's docstring)."""
    for stage, (lo, hi) in STAGES.items():
        total = record.get(f"{stage}s")
        if total:
            return lo + (hi - lo) * min(1.0, float(record.get(stage, 0)) / float(total))
    return min(0.99, float(record.get("iter", 0)) / max(expected, 1.0))


def _stage_end(record: dict) -> float:
    """Where the stage a record belongs to ends, as a fraction of its window."""
    for stage, (_, hi) in STAGES.items():
        if record.get(f"{stage}s"):
            return hi
    return 0.99


def _postfix(record: dict, windows: int) -> str:
    where = f"window {int(record.get('window', 1))}/{windows}, " if windows > 1 else ""
    for stage in STAGES:
        if record.get(f"{stage}s"):
            return f"{where}{stage} {int(record[stage])}/{int(record[stage + 's'])}"
    return f"{where}iter {int(record.get('iter', 0))}"


def _size(file) -> tuple[int, int]:
    """The terminal's (columns, lines); 0 where unknown."""
    try:
        return tuple(os.get_terminal_size(file.fileno()))
    except (AttributeError, ValueError, OSError):
        return 0, 0


def _isatty(file) -> bool:
    try:
        return bool(file.isatty())
    except (AttributeError, ValueError):
        return False
