"""Windowed fills of long recordings: the window plan and the blend of the windows' fills.

A long recording is filled in overlapping windows of ``length`` frames, so time grows linearly with
the number of frames and memory is bounded by the windows solved at once. The plan is chosen from
the gaps:

- ``overlap = 2 * longest gap`` (at least ``MIN_OVERLAP``): every gap, with half its length of
  observed context on each side, then lies whole inside at least one window;
- at most ``max(window, 3 * overlap)`` frames per window, as few windows as that allows, and the
  recording shared evenly among them with overlaps of exactly ``overlap`` (windows no shorter
  than ``3 * overlap``): most frames are solved once (12 000 frames are three windows of 4268
  frames, not of 6000 with 3000-frame overlaps, which solved 1.5x the frames);
- when the recording fits one window, that window is the unwindowed fill.

Blending: each window's fill gets a weight that ramps linearly from its edges over ``overlap``
frames (a cross-fade; no ramp at the recording's own ends), set to zero on every gap the window
cuts (a gap that does not have an observed frame of that marker, or the recording's end, on both
sides inside the window), then normalized across windows. A gap's fill is therefore a convex
combination, smooth in time, of the fills of the windows that hold it whole. Observed samples are
not blended: ``fill()`` only writes missing samples.

Order: the first window is solved alone; what its solver chose (``Solver.carry``: Tucker's ``eps``
schedule, the default's candidates and weights per gap kind) is reused by the others, each on its
share of torch's threads (:func:`lanes`). They run in worker processes of the runtime's pool
when there are at least ``PROCESS_MIN_LATER`` of them and the first window has run
``LAUNCH_AFTER`` seconds (the workers start in the background meanwhile); otherwise in threads,
where Python between torch's kernels holds them to one core at a time (see docs/speed.md, "Long
recordings"). A worker gets its window's slice and gives back its fill and error estimate only;
the fills are the same bit for bit either way.
"""
from __future__ import annotations

import math
import os
import pickle
import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .constraints import CandidatePost
from .metrics import gap_runs
from .options import WINDOW
from .runtime.cache import clear_all
from .runtime.memory import trim_heap
from .runtime.pool import Processes, report
from .runtime.threads import serial, thread_map
from .solvers import get_solver

#: Smallest overlap between windows, in frames.
MIN_OVERLAP = 100
#: Windows after the first that make worker processes worth starting (fewer run in threads).
PROCESS_MIN_LATER = 2
#: Seconds the first window runs before the workers for the later ones start (in the
#: background): a worker's start, a fresh interpreter importing torch, costs about 2 s of CPU, so
#: a faster first window leaves the later ones to threads.
LAUNCH_AFTER = 2.0


@dataclass(frozen=True)
class Plan:
    """Windows as ``(start, stop)`` frame ranges, and the overlap the cross-fade ramps over."""

    windows: tuple[tuple[int, int], ...]
    overlap: int

    @property
    def length(self) -> int:
        return max(b - a for a, b in self.windows)


def plan(missing: np.ndarray, window: int | None = WINDOW) -> Plan:
    """The window plan for a ``(T, J)`` missing mask; ``window=None`` means one window."""
    missing = np.asarray(missing, dtype=bool)
    T = missing.shape[0]
    seen = ~missing.all(axis=0)          # markers never observed are not filled at all
    longest = max((b - a for j, a, b in gap_runs(missing[:, seen])), default=0)
    overlap = max(MIN_OVERLAP, 2 * longest)
    longest_window = T if window is None else max(int(window), 3 * overlap)
    if longest_window >= T:
        return Plan(((0, T),), overlap)
    n = math.ceil((T - overlap) / (longest_window - overlap))
    length = max(math.ceil((T + (n - 1) * overlap) / n) + 1, 3 * overlap)   # +1: rounded starts
    starts = np.round(np.linspace(0, T - length, n)).astype(int)
    return Plan(tuple((int(s), int(s) + length) for s in starts), overlap)


@dataclass
class Remote:
    """How :func:`blend` hands the later windows to worker processes: ``args(start, stop)`` the
    picklable arguments of :func:`fit_remote` for a window, ``done(start, stop, result)`` its
    fill from what came back, ``report(message)`` a message a window sent while it ran."""

    args: Callable[[int, int], tuple]
    done: Callable[[int, int, Any], torch.Tensor]
    report: Callable[[Any], None] = lambda message: None


def blend(p: Plan, missing: torch.Tensor, solve: Callable[[int, int], torch.Tensor],
          workers: int | None = 1, emit: Callable[[int, int, torch.Tensor], None] | None = None,
          remote: Remote | None = None) -> torch.Tensor | None:
    """Fill every window with ``solve(start, stop)`` (a ``(stop - start, J, D)`` tensor) and blend
    the fills with :func:`weight` (any number of coordinates), in window order whatever order they
    finish in. NaN where no window fills. The first window is solved alone (what it chooses may
    carry to the others, see :meth:`Solver.carry`) with all of torch's threads, the others
    ``workers`` at a time (None: torch's thread count, also the most; see :func:`lanes`): in
    worker processes through ``remote`` where that pays (see the module notes), else in threads
    that share torch's threads out; with one worker one window's fill is held at a time.

    ``emit(start, stop, values)``, when given, receives the blended frames as soon as no later
    window reaches them, and nothing is returned: no full-length blend is held (a long
    recording's fill writes them into its result as they come). Otherwise the whole blend is
    returned."""
    T, J = missing.shape
    if emit is None:
        kept = []
        blend(p, missing, solve, workers, lambda a, b, values: kept.append(values), remote)
        return kept[0] if len(kept) == 1 else torch.cat(kept)
    starts = [a for a, _ in p.windows[1:]] + [T]      # frames before the next window's are final
    lo, num, den = 0, None, None                         # the frames [lo, lo + len(den)) in play
    for k, (a, b), part in _solved(p, solve, workers, remote):
        if len(p.windows) == 1:
            emit(0, T, part)
            return None
        w = torch.as_tensor(weight(p, k, missing[a:b].cpu().numpy(), T), dtype=part.dtype,
                            device=part.device)
        if num is None:
            num = part.new_zeros((0, J, part.shape[2]))
            den = part.new_zeros((0, J))
        if b > lo + den.shape[0]:
            grow = b - lo - den.shape[0]
            num = torch.cat([num, part.new_zeros((grow, J, part.shape[2]))])
            den = torch.cat([den, part.new_zeros((grow, J))])
        w = torch.where(torch.isfinite(part).all(dim=2), w, 0.0)
        num[a - lo:b - lo] += w[..., None] * torch.nan_to_num(part)
        den[a - lo:b - lo] += w
        n = starts[k] - lo
        if n > 0:
            d = den[:n]
            done = num[:n] / d.clamp_min(torch.finfo(d.dtype).tiny)[..., None]
            done[d == 0] = torch.nan
            emit(lo, starts[k], done)
            num, den, lo = num[n:].clone(), den[n:].clone(), starts[k]
    return None


def lanes(workers: int | None, later: int) -> tuple[int, int]:
    """``(n, share)``: the later windows ``n`` at a time, each on ``share`` threads; ``workers``
    (None: torch's thread count) capped by torch's thread count, the cores this process may run
    on and ``later``, and ``n * share`` at most the smaller of torch's threads and the cores."""
    threads = torch.get_num_threads()
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:                                   # not on Linux
        cores = os.cpu_count() or 1
    n = max(1, min(workers or threads, threads, cores, later))
    return n, max(1, min(threads, cores) // n)


def _solved(p: Plan, solve: Callable[[int, int], torch.Tensor], workers: int | None,
            remote: Remote | None):
    """``(k, (start, stop), fill)`` for every window, in order (see :func:`blend`)."""
    first, *rest = p.windows
    n, share = lanes(workers, len(rest))
    wanted = remote is not None and n > 1 and len(rest) >= PROCESS_MIN_LATER
    with _Launch(Processes(fit_remote, n, share, died=_died) if wanted else None) as launch:
        yield 0, first, solve(*first)
        pool = launch.pool()
        if pool is None:
            parts = thread_map(lambda w: solve(*w), rest, n, share=share)
            yield from ((k, w, part) for k, (w, part) in enumerate(zip(rest, parts), 1))
            return
        done, k = {}, 0                  # what came back, by window; the next one to blend
        calls = _Calls(rest, remote.args)
        for i, result in pool.run(calls, report=lambda i, message: remote.report(message)):
            done[i] = remote.done(*rest[i], result)
            while k in done:
                yield k + 1, rest[k], done.pop(k)
                k += 1


class _Calls:
    """The later windows' calls, each built when the pool hands it out (its slice is cut then,
    not all at once)."""

    def __init__(self, windows: list[tuple[int, int]], args: Callable[[int, int], tuple]):
        self.windows, self.args = windows, args

    def __len__(self) -> int:
        return len(self.windows)

    def __getitem__(self, i: int) -> tuple[tuple, dict]:
        return self.args(*self.windows[i]), {}


class _Launch:
    """Starts ``processes`` after ``LAUNCH_AFTER`` seconds in a background thread (the first
    window meanwhile runs here); :meth:`pool` stops the clock and gives the pool if it started.
    On leaving, every worker ends."""

    def __init__(self, processes: Processes | None):
        self.processes, self.timer, self.failed = processes, None, False

    def __enter__(self) -> "_Launch":
        if self.processes is not None:
            self.timer = threading.Timer(LAUNCH_AFTER, self._launch)
            self.timer.daemon = True
            self.timer.start()
        return self

    def _launch(self) -> None:
        try:
            self.processes.launch()
        except Exception:                   # no workers (out of processes): threads instead
            self.failed = True
            self.processes.close()

    def pool(self) -> Processes | None:
        if self.timer is None:
            return None
        self.timer.cancel()
        self.timer.join()
        return self.processes if self.processes.started and not self.failed else None

    def __exit__(self, *exc) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer.join()
            self.processes.close()


def _died(i: int, how: str):
    raise RuntimeError(f"the worker process of a window died ({how}) on both tries")


def weight(p: Plan, k: int, missing: np.ndarray, T: int) -> np.ndarray:
    """Unnormalized blend weight ``(stop - start, J)`` of window ``k`` given its missing mask: the
    cross-fade ramp, zero on the gaps the window cuts."""
    a, b = p.windows[k]
    w = np.repeat(_ramp(a, b, T, p.overlap)[:, None], missing.shape[1], axis=1)
    for j, s, e in gap_runs(missing):
        if (s == 0 and a > 0) or (e == b - a and b < T) or (s == 0 and e == b - a):
            w[s:e, j] = 0.0
    return w


def _ramp(a: int, b: int, T: int, overlap: int) -> np.ndarray:
    """Cross-fade weight of window ``[a, b)``: linear from its inner edges over ``overlap``."""
    t = np.arange(a, b)
    w = np.ones(b - a)
    if a > 0:
        w = np.minimum(w, (t - a + 1) / (overlap + 1))
    if b < T:
        w = np.minimum(w, (b - t) / (overlap + 1))
    return w


@dataclass
class Job:
    """What every window of one fill is fitted with (it travels to worker processes)."""

    method: str
    params: dict          # the method's hyperparameters, with what the first window chose
    extra: dict           # fit data: segments, the post-step, training recordings
    windows: int          # how many windows the fill has
    markers: torch.Tensor     # the markers the windows hold (indices into the recording's)
    return_std: bool = False
    constraints: bool = True


@dataclass
class Solved:
    """One window's fit: its fill, error estimate (or None), the fills the soft distances keep
    (``auto``'s segments, or None), its iterations and what it chose (:meth:`Solver.carry`)."""

    fill: torch.Tensor
    std: torch.Tensor | None
    anchored: torch.Tensor | None
    n_iter: int
    carry: dict


def fit(job: Job, X: torch.Tensor, missing: torch.Tensor, key: tuple[int, int], window: int,
        update: Callable[[dict], None] | None = None, solve: Callable | None = None) -> Solved:
    """Solve one window ``key`` (frames ``[start, stop)``; number ``window`` from 1): a fresh
    solver of ``job.method`` fitted to ``X`` (NaN where ``missing``) by ``solve`` (default: its
    own loop, see :func:`torchfill.filling.fill_case`), each iteration's record given to
    ``update``. The error estimate is the solver's ``std_`` (``auto``) or, with
    ``job.return_std``, the method's hold-out error by gap kind (:func:`holdout_std`)."""
    solver = get_solver(job.method, **job.params)
    where = {"window": window, "windows": job.windows, "max_iter": solver.max_iter}
    update = update or (lambda record: None)
    (solve or _fit)(solver, X, missing, job.extra, lambda d: update({**where, **d}),
                    (slice(*key), job.markers))
    filled = solver.transform(X)
    carry = solver.carry()
    est = getattr(solver, "std_", None)
    if est is None and job.return_std:
        est = holdout_std(job.method, {**job.params, **carry}, X, missing, seed=solver.seed,
                          post=CandidatePost() if job.constraints else None, **job.extra)
    return Solved(filled, None if est is None else est.to(filled.dtype),
                  getattr(solver, "anchored_", None), solver.n_iter_, carry)


def fit_remote(job: Job, X: torch.Tensor, missing: torch.Tensor, key: tuple[int, int],
               window: int, relay: bool) -> tuple[Solved | Exception, list]:
    """:func:`fit` in a worker process: as a window thread runs it (nested thread maps here), its
    records sent back when ``relay``; returns what it solved (its own tensors only) or the error
    it raised, and the warnings it gave (for the caller to give)."""
    with warnings.catch_warnings(record=True) as caught, serial():
        warnings.simplefilter("always")
        try:
            got = fit(job, X, missing, key, window, report if relay else None)
            got = Solved(*(v.clone() if isinstance(v, torch.Tensor) else v
                           for v in (got.fill, got.std, got.anchored, got.n_iter, got.carry)))
        except Exception as err:                     # given back, raised by the caller
            got = err if _picklable(err) else RuntimeError(f"{type(err).__name__}: {err}")
    clear_all()                             # the next window is other data
    trim_heap()
    return got, [(w.message, w.category, w.filename, w.lineno) for w in caught]


def warn_again(caught: list, registry: dict) -> None:
    """Give the warnings a worker caught (:func:`fit_remote`) here, under this process's
    filters, each text once per ``registry`` as the default filter does."""
    for message, category, filename, lineno in caught:
        warnings.warn_explicit(message, category, filename, lineno, registry=registry)


def _picklable(value: Any) -> bool:
    try:
        pickle.loads(pickle.dumps(value))
    except Exception:
        return False
    return True


def _fit(solver, X: torch.Tensor, missing: torch.Tensor, data: dict, callback, part) -> None:
    """The default ``solve`` of :func:`fit`: the solver's own loop."""
    solver.fit(X, missing, callback=callback, **data)


def holdout_std(method: str, params: dict, X: torch.Tensor, missing: torch.Tensor, seed: int = 0,
                post=None, **data) -> torch.Tensor:
    """Error estimate (T, J) for a fill by ``method`` (one that has no own): ``auto`` run with that
    method as its only candidate, i.e. the method's held-out error on gaps of each kind.
    ``data``: the method's fit data (``training=``); ``post``: the post-step, as fill()'s."""
    solver = get_solver("auto", candidates=(method,), candidate_params={method: dict(params)},
                        seed=seed)
    solver.fit(X, missing, post=post, **data)
    return solver.std_
