"""Helpers shared by the I/O tests: the shared recordings to parametrize over, and synthetic
recordings that need no shared data.

(Test modules import this by name; they must not import ``conftest``, since pytest swaps the
``conftest`` module between test folders.)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from torchfill.data import data_dir
from torchfill.sequence import MarkerSequence


REPO_ROOT = Path(__file__).resolve().parents[2]
DATA_DIR = data_dir(REPO_ROOT)


def data_files(*suffixes: str) -> list[Path]:
    """Recordings in the shared data folder with one of the given suffixes (the same folder as
    the ``data_dir`` fixture; empty when absent, so parametrized tests simply do not run)."""
    if not DATA_DIR.is_dir():
        return []
    wanted = {s.lower() for s in suffixes}
    return sorted(p for p in DATA_DIR.iterdir() if p.suffix.lower() in wanted)


def synthetic(T: int = 60, J: int = 5, *, seed: int = 0, gaps: bool = True,
              units: str = "mm") -> MarkerSequence:
    """A smooth random recording, in mm, with a few NaN gaps."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2, T)[:, None, None]
    phase = rng.uniform(0, 2 * np.pi, (1, J, 3))
    points = 400 + 150 * np.sin(2 * np.pi * t + phase) + rng.normal(0, 5, (1, J, 3))
    if gaps:
        points[10:20, 1] = np.nan
        points[T - 5:, J - 1] = np.nan
    return MarkerSequence(points=points, labels=[f"MK{j}" for j in range(J)], rate=120.0,
                          units=units)


def linear_fill(points: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Fill interior gaps of at most ``max_gap`` frames by linear interpolation (NumPy only).

    Returns the filled points and the ``(T, J)`` mask of filled samples; a fast stand-in for
    ``torchfill.fill(..., "linear", max_gap=...)`` in the write-back tests.
    """
    out = points.copy()
    missing = ~np.isfinite(points).all(axis=2)
    filled = np.zeros(missing.shape, bool)
    T = points.shape[0]
    for j in np.flatnonzero(missing.any(axis=0) & ~missing.all(axis=0)):
        m = missing[:, j]
        edges = np.flatnonzero(np.diff(np.r_[0, m.view(np.int8), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            if a == 0 or b == T or b - a > max_gap:
                continue
            w = (np.arange(a, b) - (a - 1)) / (b - a + 1)
            out[a:b, j] = (1 - w)[:, None] * points[a - 1, j] + w[:, None] * points[b, j]
            filled[a:b, j] = True
    return out, filled


def longest_run(flags: np.ndarray) -> tuple[int, int]:
    """``(start, stop)`` of the longest run of True in a 1-D bool array ((0, 0) if none)."""
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(np.int8), 0]))
    if not len(edges):
        return 0, 0
    starts, stops = edges[::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k])
