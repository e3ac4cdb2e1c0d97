"""Seeded gap generators, one per protocol in the papers. Each returns a gap mask ``(T, J)``
(True = missing) and never touches data; apply it with ``points[mask] = nan``.

Every generator takes ``seed`` (an int) and is deterministic for it. ``generate(name, T, J, **kw)``
dispatches by protocol name (used by the CLI and the experiment configs).
"""
from __future__ import annotations

import numpy as np


def _check(T: int, J: int, n_markers: int | None = None, gap_length: int | None = None) -> None:
    if T < 1 or J < 1:
        raise ValueError(f"need at least one frame and one marker, found T={T}, J={J}")
    if n_markers is not None and not 1 <= n_markers <= J:
        raise ValueError(f"n_markers expected 1..{J}, found {n_markers}")
    if gap_length is not None and not 1 <= gap_length < T:
        raise ValueError(f"gap_length expected 1..{T - 1} (shorter than the {T}-frame recording), "
                         f"found {gap_length}")


def multi_gap(T: int, J: int, *, n_markers: int = 20, gap_length: int = 100, max_gaps: int = 5,
              seed: int = 0) -> np.ndarray:
    """Mohaoui & Dmytryshyn 2026 (Tucker paper): ``n_markers`` random markers, each with
    ``K_m = max(1, round(U * max_gaps))`` gaps of ``gap_length`` frames, U ~ uniform(0, 1),
    each start uniform in the first ``T / 5.1 * 4`` frames (as in the authors' demo) and clipped
    so the gap fits in the recording. Gaps on one marker may overlap."""
    _check(T, J, n_markers, gap_length)
    if max_gaps < 1:
        raise ValueError(f"max_gaps expected >= 1, found {max_gaps}")
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    last_start = max(1, min(int(T * 4 / 5.1), T - gap_length + 1))
    for j in rng.choice(J, size=n_markers, replace=False):
        K = max(1, int(round(rng.uniform() * max_gaps)))
        for start in rng.integers(0, last_start, size=K):
            mask[start:start + gap_length, j] = True
    return mask


def shared_window(T: int, J: int, *, n_markers: int = 10, gap_length: int = 50,
                  seed: int = 0) -> np.ndarray:
    """Mohaoui & Dmytryshyn 2024 (CP paper): ``n_markers`` random markers all missing over the same
    window of ``gap_length`` frames, its start uniform over the recording."""
    _check(T, J, n_markers, gap_length)
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    start = int(rng.integers(0, T - gap_length + 1))
    mask[start:start + gap_length, rng.choice(J, size=n_markers, replace=False)] = True
    return mask


def evenly_spaced(T: int, J: int, *, n_gaps: int = 5, gap_length: int = 50,
                  seed: int = 0) -> np.ndarray:
    """Li et al. 2020 (Tables 1-2): ``n_gaps`` gaps of ``gap_length`` frames, their starts evenly
    spaced over the recording, each on a different random marker (markers reused only if
    ``n_gaps > J``)."""
    _check(T, J, None, gap_length)
    if n_gaps < 1:
        raise ValueError(f"n_gaps expected >= 1, found {n_gaps}")
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    starts = np.linspace(0, T - gap_length, n_gaps).round().astype(int)
    markers = rng.permutation(np.resize(rng.permutation(J), n_gaps))
    for start, j in zip(starts, markers):
        mask[start:start + gap_length, j] = True
    return mask


def blackout(T: int, J: int, *, gap_length: int = 20, start: int | None = None,
             seed: int = 0) -> np.ndarray:
    """Li et al. 2020 (Eq. 9-16, Fig. 8): every marker missing over ``gap_length`` whole frames,
    starting at ``start`` (default: uniform, never touching the first or last frame)."""
    _check(T, J, None, gap_length)
    if start is None:
        rng = np.random.default_rng(seed)
        start = int(rng.integers(1, max(2, T - gap_length)))
    if not 0 <= start <= T - gap_length:
        raise ValueError(f"blackout start expected 0..{T - gap_length}, found {start}")
    mask = np.zeros((T, J), dtype=bool)
    mask[start:start + gap_length] = True
    return mask


def random_entries(T: int, J: int, *, rate: float = 0.2, seed: int = 0) -> np.ndarray:
    """Imamura & Okuda 2018 (Fig. 1a): each (frame, marker) sample missing independently with
    probability ``rate``; every marker keeps at least one observed frame."""
    if not 0.0 <= rate < 1.0:
        raise ValueError(f"rate expected in [0, 1), found {rate}")
    _check(T, J)
    rng = np.random.default_rng(seed)
    mask = rng.random((T, J)) < rate
    full = mask.all(axis=0)
    mask[rng.integers(0, T, size=full.sum()), np.flatnonzero(full)] = False
    return mask


def continuous_runs(T: int, J: int, *, n_markers: int = 10, gap_length: int = 40,
                    seed: int = 0) -> np.ndarray:
    """Imamura & Okuda 2018 (Fig. 1b): ``n_markers`` random markers each missing one run of
    ``gap_length`` frames, at independent uniform start times."""
    _check(T, J, n_markers, gap_length)
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    for j in rng.choice(J, size=n_markers, replace=False):
        start = int(rng.integers(0, T - gap_length + 1))
        mask[start:start + gap_length, j] = True
    return mask


PROTOCOLS = {
    "multi_gap": multi_gap,
    "shared_window": shared_window,
    "evenly_spaced": evenly_spaced,
    "blackout": blackout,
    "random_entries": random_entries,
    "continuous_runs": continuous_runs,
}


def generate(protocol: str, T: int, J: int, **kwargs) -> np.ndarray:
    """Dispatch to the generator named ``protocol`` (see ``PROTOCOLS``)."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown gap protocol {protocol!r}; expected one of {', '.join(PROTOCOLS)}")
    return PROTOCOLS[protocol](T, J, **kwargs)
