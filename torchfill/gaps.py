"""Seeded gap generators, one per protocol in the papers. Each returns a gap mask ``(T, J)``
(True = missing) and never touches data; apply it with ``points[mask] = nan``.

Every generator takes ``seed`` (an int) and is deterministic for it. ``generate(name, T, J, **kw)``
dispatches by protocol name (used by the CLI and the experiment configs).
"""
from __future__ import annotations

import warnings

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


# --- evaluation suites: masks shaped by the data or the trial ends ----------------------------
def trial_ends(T: int, J: int, *, n_markers: int, gap_length: int, seed: int = 0) -> np.ndarray:
    """Half of ``n_markers`` random markers missing the first ``gap_length`` frames, the other
    half the last ``gap_length`` frames (what real recordings lose most)."""
    _check(T, J, n_markers, gap_length)
    rng = np.random.default_rng(seed)
    chosen = rng.choice(J, size=n_markers, replace=False)
    mask = np.zeros((T, J), dtype=bool)
    mask[:gap_length, chosen[::2]] = True
    mask[T - gap_length:, chosen[1::2]] = True
    return mask


def still_window(points: np.ndarray, *, n_markers: int, gap_length: int,
                 seed: int = 0) -> np.ndarray:
    """``n_markers`` random markers missing together over the ``gap_length`` frames (not touching
    the ends) where the mean marker speed of ``points`` (T, J, 3) is smallest."""
    T, J, _ = points.shape
    _check(T, J, n_markers, gap_length + 2)
    speed = np.linalg.norm(np.diff(points, axis=0), axis=2).mean(axis=1)      # (T-1,)
    run = np.convolve(speed, np.ones(gap_length), "valid")                     # window sums
    start = 1 + int(np.argmin(run[1:T - gap_length - 1]))
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    mask[start:start + gap_length, rng.choice(J, size=n_markers, replace=False)] = True
    return mask


def clustered(points: np.ndarray, *, seed: int = 0, min_len: int = 30,
              max_len: int = 120) -> np.ndarray:
    """Clustered occlusions: a marker without a gap yet and its 1-4 nearest neighbours (mean
    distance in ``points`` (T, J, 3)) vanish together for ``min_len``-``max_len`` frames, until
    every marker has a gap. No frame loses every marker."""
    T, J, _ = points.shape
    D = np.linalg.norm(points[:, :, None] - points[:, None], axis=3).mean(axis=0)   # (J, J)
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    while not mask.any(axis=0).all():
        j = rng.choice(np.flatnonzero(~mask.any(axis=0)))
        cluster = np.argsort(D[j])[: 1 + int(rng.integers(1, 5))]
        L = int(rng.integers(min_len, min(max_len, T // 3) + 1))
        start = int(rng.integers(0, T - L + 1))
        trial = mask.copy()
        trial[start:start + L, cluster] = True
        if not trial.all(axis=1).any():
            mask = trial
    return mask


def grouped_windows(points: np.ndarray, *, groups: int = 6, windows: int = 2,
                    seed: int = 0) -> np.ndarray:
    """Every marker has a gap: markers grouped by mean position in ``points`` (T, J, 3) (nearest
    of ``groups`` random markers), each group hidden over ``windows`` windows of 30-100 frames,
    each marker's start and end jittered by up to 5 frames."""
    rng = np.random.default_rng(seed)
    T, J = points.shape[:2]
    centre = points.mean(axis=0)
    seeds = rng.choice(J, size=groups, replace=False)
    group = np.argmin(((centre[:, None] - centre[seeds][None]) ** 2).sum(axis=2), axis=1)
    mask = np.zeros((T, J), dtype=bool)
    for g in range(groups):
        for _ in range(windows):
            length = int(rng.integers(30, 101))
            start = int(rng.integers(0, T - length))
            for j in np.flatnonzero(group == g):
                a = max(0, start + int(rng.integers(-5, 6)))
                mask[a:min(T, a + length + int(rng.integers(-5, 6))), j] = True
    return mask


# --- real gap patterns -------------------------------------------------------------------------

def vertical_axis(points: np.ndarray) -> int:
    """The axis along which a standing body is longest: the median over frames of each axis'
    extent of the observed markers (a person is taller than wide in almost every frame)."""
    P = np.asarray(points, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)             # blackout frames
        extent = np.nanmax(P, axis=1) - np.nanmin(P, axis=1)        # (T, 3)
        return int(np.argmax(np.nanmedian(extent, axis=0)))


def body_side(label: str) -> float:
    """-1 for a left, +1 for a right, 0 for a midline marker, read from the label (``LFHD``,
    ``L_ASIS``, ``L.Knee``, ``Derrick:LSHO``, ``l should``, ``LeftAnkle``)."""
    name = label.rsplit(":", 1)[-1].strip()
    for side, sign in (("l", -1.0), ("r", 1.0)):
        low = name.lower()
        if low.startswith(("left" if side == "l" else "right")):
            return sign
        if low[:1] == side and len(name) > 1 and (name[1] in "_. -" or name[1].isupper()
                                                  or name[1].isdigit()):
            return sign
    return 0.0


def body_layout(points: np.ndarray, labels) -> np.ndarray:
    """``(J, 3)`` place of each marker on the body, free of units, facing and lab axes: height
    (0 = lowest, 1 = highest marker, along :func:`vertical_axis`), side (-1 left, +1 right, from
    the label), distance from the body's vertical axis (in heights). NaN for a marker never
    observed."""
    P = np.asarray(points, dtype=np.float64)
    v = vertical_axis(P)
    h = P[..., v]
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # blackouts, never-seen markers
        low, high = np.nanmin(h, axis=1, keepdims=True), np.nanmax(h, axis=1, keepdims=True)
        size = np.nanmedian(high - low)
        height = np.nanmedian((h - low) / np.maximum(high - low, 1e-12), axis=0)
        flat = np.delete(P, v, axis=2)
        centre = np.nanmean(flat, axis=1, keepdims=True)
        radial = np.nanmedian(np.linalg.norm(flat - centre, axis=2), axis=0) / max(size, 1e-12)
    side = np.array([body_side(str(s)) for s in labels])
    return np.stack([height, side, radial], axis=1)


def transplant(source: np.ndarray, T: int, J: int, *, seed: int = 0, rate_ratio: float = 1.0,
               source_layout: np.ndarray | None = None, target_layout: np.ndarray | None = None,
               max_missing: float = 0.95) -> np.ndarray:
    """A real recording's gap pattern laid onto another recording of ``T`` frames, ``J`` markers.

    ``source`` is the ``(Ts, Js)`` missing mask of a real gapped file. It is resampled in time by
    ``rate_ratio`` (target rate / source rate, nearest frame) so that gaps keep their duration in
    seconds; source markers missing in more than ``max_missing`` of the frames (dead markers,
    probes, model outputs) are dropped. The pattern is cut to ``T`` frames at a seeded offset
    (trial-end gaps stay at the trial ends when ``T`` equals the resampled length). Each kept
    source marker goes to one target marker: at random (seeded), or -- given both layouts
    (:func:`body_layout`) -- to the target marker at the most similar place on the body (a
    minimum-cost assignment; real occlusions hit neighbouring markers together). Target markers
    left over stay complete; extra source markers (more than ``J``) are dropped at random.
    """
    S = np.asarray(source, dtype=bool)
    keep = np.flatnonzero(S.mean(axis=0) <= max_missing)
    S = S[:, keep]
    rng = np.random.default_rng(seed)
    Ts = max(1, int(round(S.shape[0] * rate_ratio)))
    S = S[np.minimum((np.arange(Ts) / rate_ratio).round().astype(int), S.shape[0] - 1)]
    if Ts > T:
        start = int(rng.integers(0, Ts - T + 1))
        S = S[start:start + T]
    elif Ts < T:
        raise ValueError(f"the gap pattern has {Ts} frames, fewer than the {T} to cover: cut the "
                         f"target recording to {Ts} frames")
    if S.shape[1] > J:
        pick = np.sort(rng.choice(S.shape[1], size=J, replace=False))
        S, keep = S[:, pick], keep[pick]
    mask = np.zeros((T, J), dtype=bool)
    if source_layout is None or target_layout is None:
        target = rng.permutation(J)[:S.shape[1]]
    else:
        from scipy.optimize import linear_sum_assignment
        a = np.nan_to_num(np.asarray(source_layout, dtype=np.float64)[keep], nan=1e3)
        b = np.nan_to_num(np.asarray(target_layout, dtype=np.float64), nan=1e3)
        cost = np.linalg.norm((a[:, None] - b[None]) * LAYOUT_WEIGHTS, axis=2)
        cost += 1e-6 * rng.random(cost.shape)                     # seeded tie-breaks
        rows, target = linear_sum_assignment(cost)
        target = target[np.argsort(rows)]
    mask[:, target] = S
    return mask


#: Weights of height, side and radial distance when markers are matched by body layout: the side
#: counts as much as a tenth of the body's height (left and right markers are never swapped
#: where a same-side marker exists nearby).
LAYOUT_WEIGHTS = np.array([1.0, 0.1, 1.0])
