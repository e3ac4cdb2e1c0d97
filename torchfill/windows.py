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
schedule, the default's candidates and weights per gap kind) is reused by the others, which run
in threads, each on its share of torch's threads (bench_long 120 000 frames on 2 cores,
``tucker_tnn``: 96 s one window at a time with 2 threads, 52 s two at a time with one each).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from .metrics import gap_runs
from .options import WINDOW
from .runtime.threads import thread_map

#: Smallest overlap between windows, in frames.
MIN_OVERLAP = 100


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


def blend(p: Plan, missing: torch.Tensor, solve: Callable[[int, int], torch.Tensor],
          workers: int | None = 1, emit: Callable[[int, int, torch.Tensor], None] | None = None
          ) -> torch.Tensor | None:
    """Fill every window with ``solve(start, stop)`` (a ``(stop - start, J, D)`` tensor) and blend
    the fills with :func:`weight` (any number of coordinates), in window order whatever order they
    finish in. NaN where no window fills. The first window is solved alone (what it chooses may
    carry to the others, see :meth:`Solver.carry`) with all of torch's threads, the others
    ``workers`` at a time (None: torch's thread count, also the most) in threads that share
    torch's threads out (its kernels release the GIL); with one worker one window's fill is held
    at a time.

    ``emit(start, stop, values)``, when given, receives the blended frames as soon as no later
    window reaches them, and nothing is returned: no full-length blend is held (a long
    recording's fill writes them into its result as they come). Otherwise the whole blend is
    returned."""
    T, J = missing.shape
    if emit is None:
        kept = []
        blend(p, missing, solve, workers, lambda a, b, values: kept.append(values))
        return kept[0] if len(kept) == 1 else torch.cat(kept)
    starts = [a for a, _ in p.windows[1:]] + [T]      # frames before the next window's are final
    lo, num, den = 0, None, None                         # the frames [lo, lo + len(den)) in play
    for k, (a, b), part in _solved(p, solve, workers):
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


def _solved(p: Plan, solve: Callable[[int, int], torch.Tensor], workers: int | None):
    """``(k, (start, stop), fill)`` for every window, in order (see :func:`blend`)."""
    first, *rest = p.windows
    yield 0, first, solve(*first)
    parts = thread_map(lambda w: solve(*w), rest, workers)
    yield from ((k, w, part) for k, (w, part) in enumerate(zip(rest, parts), 1))


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
