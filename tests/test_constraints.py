"""The constraints post-step that fill() applies by default: observed samples untouched, no
teleport on a real gap file, samples inside the observed volume, continuity at gap edges,
rigid donors used, and constraints=False giving the method's own fill."""
from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import torch

import torchfill
from torchfill import metrics
from torchfill.constraints import RiskyFillWarning, constrain
from torchfill.solvers import get_solver
from benchmarks.suites.qc import PLAUSIBLE_FILES


def _walk(T=200, J=6, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 100.0
    return 300 * np.sin(2 * np.pi * 0.5 * t + rng.uniform(0, 6, size=(1, J, 3))) + \
        rng.normal(0, 400, size=(1, J, 3)) + 800 * t


def test_teleport_in_a_fill_is_removed_and_edges_kept():
    X = _walk()
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[50:90, 2] = True
    F = X.copy()
    F[70:90, 2] += 900.0                 # a fill that jumps 900 mm in one frame
    out, report = constrain(F, missing)
    observed = ~missing
    assert np.array_equal(out[observed], X[observed])
    limit = metrics.step_limit(X, observed)
    assert metrics.teleports(F, missing, limit) >= 1
    assert metrics.teleports(out, missing, limit) == 0
    assert report.shortened_gaps == 1
    assert metrics.outside_volume(out, missing, metrics.volume(X, observed)) == 0


def test_edge_blending_makes_the_fill_continue_the_trajectory():
    X = _walk()
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[60:100, 1] = True
    F = X.copy()
    F[60:100, 1] += 40.0                 # an offset fill: a 40 mm jump at both edges
    before = metrics.edge_jumps(F, missing).max()
    out, _ = constrain(F, missing)
    assert metrics.edge_jumps(out, missing).max() < 0.1 * before
    # the offset is gone: the blended fill is near the truth everywhere in the gap
    assert np.abs(out[60:100, 1] - X[60:100, 1]).max() < 5.0


def test_trial_end_offset_fades_so_a_good_fill_far_from_the_edge_is_kept():
    from torchfill.constraints import END_FADE
    X = _walk()
    X[148] += 15.0                       # noise on the last observed sample: a velocity kink
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[150:, 3] = True              # lost for the rest of the trial
    F = X.copy()
    off = np.clip(1.0 - np.arange(50) / END_FADE, 0.0, None)[:, None]
    F[150:, 3] += 40.0 * off             # a spatial fill 40 mm off at the edge, right further on
    out, _ = constrain(F, missing)
    assert metrics.edge_jumps(out, missing).max() < 0.1 * metrics.edge_jumps(F, missing).max()
    # the edge offset is not carried over the whole gap: the fill stays right beyond the fade
    assert np.abs(out[150 + END_FADE:, 3] - X[150 + END_FADE:, 3]).max() < 1e-9


def test_extrapolation_limit_leaves_the_far_end_unfilled_with_a_warning():
    X = _walk()
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[150:, 4] = True
    with pytest.warns(RiskyFillWarning, match="extrapolat"):
        out, report = constrain(X.copy(), missing, extrapolate=10)
    assert np.isfinite(out[150:160, 4]).all() and np.isnan(out[160:, 4]).all()
    assert report.unfilled_extrapolation == 40


def test_the_extrapolation_count_is_what_stays_unfilled():
    """A blackout inside a spatially filled trial end: the limit drops its frames, the blackout
    interpolation fills them again; the warning counts only what the output leaves NaN."""
    X = _walk()
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[150:, 4] = True
    missing[170:180] = True                     # no marker seen in these frames
    F = X.copy()
    F[missing] = X[missing] + 1.0               # a spatial method's fill
    out, report = constrain(F, missing, extrapolate=5, spatial=True)
    left = int((missing & ~np.isfinite(out).all(axis=2)).sum())
    assert report.unfilled_extrapolation == left


def test_blackout_frames_are_interpolated_not_invented():
    X = _walk()
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[100:110] = True              # no marker seen in these frames
    F = X.copy()
    F[100:110] = 1e4                     # whatever a method would invent there
    with pytest.warns(RiskyFillWarning, match="no marker observed"):
        out, _ = constrain(F, missing)
    t = np.arange(100, 110)
    expected = X[99] + (X[110] - X[99]) * ((t - 99) / 11.0)[:, None, None]
    # interpolated in time (then blended to continue the trajectory at its edges)
    assert np.abs(out[100:110] - expected).max() < 5.0


def test_constraints_false_is_the_methods_own_fill(recording):
    """The method's own fill, with the samples the file marks as filled earlier (residual 0)
    treated as gaps for the fit and kept as they were."""
    seq = torchfill.read(recording("c3dorg_s02_pc_real.c3d"))
    prior = seq.meta["filled"]
    X = torch.from_numpy(seq.points)
    own = get_solver("pchip").fit_transform(X, torch.from_numpy(seq.mask | prior)).numpy()
    own[prior] = seq.points[prior]
    out = torchfill.fill(seq, "pchip", constraints=False)
    assert np.array_equal(out.points, own, equal_nan=True)


@pytest.mark.parametrize("name", ["c3dorg_s02_pc_real.c3d", "c3dorg_s26_walking_hybrid_1_5.c3d"])
def test_no_teleport_on_a_real_gap_file(recording, name):
    """The default fill on real gaps: no step beyond 1.5 x the 99.9th-percentile observed step,
    nothing outside the observed volume, observed samples bit-for-bit; the method alone teleports
    on hybrid_1_5 (R_ASIS drops ~360 mm in one frame)."""
    seq = torchfill.read(recording(name))
    earlier = seq.meta.get("filled")          # marked as filled in the file: not observations
    observed = ~seq.mask & ~(earlier if earlier is not None else False)
    limit = metrics.step_limit(seq.points, observed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq, "tucker_tnn", max_iter=150)
        raw = torchfill.fill(seq, "tucker_tnn", max_iter=150, constraints=False)
    assert np.array_equal(out.points[~seq.mask], seq.points[~seq.mask])     # earlier fills too
    assert metrics.teleports(out.points, seq.mask, limit) == 0
    assert metrics.outside_volume(out.points, seq.mask, metrics.volume(seq.points, observed)) == 0
    if "hybrid_1_5" in name:
        assert metrics.teleports(raw.points, seq.mask, limit) > 0


def test_blocks_of_pairs_and_frames_do_not_change_the_result(recording, monkeypatch):
    """Rigid pairs and soft distances are computed a block at a time so that long recordings
    fit in memory: pair blocks give the same bits as one block, frame blocks the same up to the
    rounding of a matrix product with fewer rows (frames are independent there)."""
    from torchfill import constraints
    from torchfill.solvers import rigid_pairs

    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_5.c3d"))
    F = torchfill.fill(seq, "linear", constraints=False).points
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole, _ = constrain(F, seq.mask)
        monkeypatch.setattr(rigid_pairs, "PAIR_BLOCK", 1)
        assert np.array_equal(constrain(F, seq.mask)[0], whole, equal_nan=True)
        monkeypatch.setattr(constraints, "SOFT_BLOCK", 1)
        blocked = constrain(F, seq.mask)[0]
    np.testing.assert_allclose(blocked, whole, rtol=0, atol=1e-9)
    assert np.array_equal(blocked[~seq.mask], seq.points[~seq.mask])
    assert np.nanmax(np.abs(whole - F)) > 1.0                       # the constraints did move fills


def test_soft_distances_leave_a_pair_that_bends_now_and_then():
    """A pair whose distance is constant in most frames (a median-based spread calls it rigid)
    but bends in 20 % of them: a correct fill inside the bend must not be pulled back to the
    still-time distance."""
    T = 600
    t = np.arange(T) / 120.0
    rng = np.random.default_rng(0)
    base = np.stack([300 * np.sin(0.8 * t), 200 * np.cos(0.5 * t), 900 + 50 * np.sin(1.3 * t)], 1)
    bend = np.where((t >= 200 / 120) & (t < 320 / 120), np.sin(np.pi * (t - 200 / 120) / 1.0), 0)
    d = 100 + 60 * np.clip(bend, 0, None)                                 # 100 mm, up to 160
    X = np.stack([base, base + d[:, None] * np.array([1.0, 0, 0]),
                  base + [400, 300, 0], base + [-500, 200, 100]], 1) + rng.normal(0, 0.3, (T, 4, 3))
    missing = np.zeros((T, 4), dtype=bool)
    missing[230:290, 1] = True                                           # inside the bend
    out, _ = constrain(X.copy(), missing)                                # the fill is the truth
    assert np.abs(out[missing] - X[missing]).max() < 5.0                 # mm (before: 24 mm)
    assert np.array_equal(out[~missing], X[~missing])


def test_soft_distances_hold_a_rigid_pair_with_a_tiny_spread_and_rare_jitter():
    """A rigid pair seen almost still (spread ~0.1 mm) with jitter in a tenth of its frames: its
    p95 deviation (~4 mm) is below the rigidity tolerance, so it is held although it exceeds three
    of its own (tiny) bands (numediart_03_rolling's LR_FM5-LR_FM2 was dropped: torn to 300 mm)."""
    T = 600
    t = np.arange(T) / 120.0
    rng = np.random.default_rng(1)
    base = np.stack([300 * np.sin(0.8 * t), 200 * np.cos(0.5 * t), 900 + 50 * np.sin(1.3 * t)], 1)
    jitter = rng.normal(0, 0.05, (T, 3)) + (rng.random(T) < 0.1)[:, None] * rng.normal(0, 4, (T, 3))
    X = np.stack([base, base + [70.0, 0, 0] + jitter, base + [400, 300, 0],
                  base + [-500, 200, 100]], 1)
    missing = np.zeros((T, 4), dtype=bool)
    missing[200:260, 1] = True
    F = X.copy()
    F[200:260, 1] += 40 * np.sin(np.linspace(0, np.pi, 60))[:, None] * [0, 1.0, 0]   # a bulge
    out, _ = constrain(F, missing)
    d = np.linalg.norm(out[200:260, 1] - out[200:260, 0], axis=1)
    assert np.abs(d - 70).max() < 3.0                                    # mm (before: 12.6 mm)
    assert np.array_equal(out[~missing], X[~missing])


def test_soft_distances_leave_a_pair_seen_only_while_still_free_to_bend():
    """An upper-arm marker seen only in a still fifth of the trial measures a constant distance
    to the wrist; when the elbow bends in its gap, the fill that follows the bend is kept, not
    pulled back to that distance (numediart_03_rolling's mask on hdm05_bd_05-01)."""
    T = 600
    t = np.arange(T) / 120.0
    bend = np.where(np.arange(T) < 120, 0.0, 1.2 * np.sin(np.pi * (np.arange(T) - 120) / 480))
    shoulder = np.stack([np.zeros(T), np.zeros(T), np.full(T, 1400.0)], 1)
    elbow = shoulder + [0, 0, -300.0]
    wrist = elbow + 250 * np.stack([np.sin(bend), np.zeros(T), -np.cos(bend)], 1)
    upper = shoulder + [0, 40.0, -150]                                  # on the upper arm
    pelvis = np.stack([200 * np.sin(0.3 * t), np.zeros(T), np.full(T, 900.0)], 1)
    X = np.stack([upper, wrist, elbow, pelvis], 1)    # two rigid partners: no rigid donors
    missing = np.zeros((T, 4), dtype=bool)
    missing[120:, 0] = True                 # the upper-arm marker: seen only before the bend
    out, _ = constrain(X, missing)          # the fill is the truth
    assert np.abs(out[120:, 0] - X[120:, 0]).max() < 2.0   # mm (held to 402 mm: 27 mm off)
    assert np.array_equal(out[~missing], X[~missing])


def test_soft_distances_hold_an_anchored_fill_still_and_move_its_partner():
    """auto's fills from segment-mates are anchored: the soft distances move only the partner."""
    T = 600
    t = np.arange(T) / 120.0
    base = np.stack([300 * np.sin(0.8 * t), 200 * np.cos(0.5 * t), 900 + 50 * np.sin(1.3 * t)], 1)
    other = np.stack([200 * np.sin(2.1 * t), 300 * np.cos(1.7 * t), 700 + 90 * np.sin(3.1 * t)], 1)
    turn = 0.8 * np.sin(0.9 * t)           # the pair turns, so its distance is seen in many poses
    arm = 70.0 * np.stack([np.cos(turn), np.sin(turn), np.zeros(T)], 1)
    X = np.stack([base, base + arm, other, -other + [0, 0, 1800]], 1)   # one rigid pair
    missing = np.zeros((T, 4), dtype=bool)
    missing[200:260, :2] = True            # both markers of a rigid pair missing together
    F = X.copy()
    F[200:260, 1] += 40 * np.sin(np.linspace(0, np.pi, 60))[:, None] * [0, 1.0, 0]   # a bulge
    anchored = np.zeros_like(missing)
    anchored[200:260, 0] = True             # marker 0's fill is exact
    out, _ = constrain(F, missing, anchored=anchored)
    assert np.abs(out[200:260, 0] - X[200:260, 0]).max() < 0.1
    d = np.linalg.norm(out[200:260, 1] - out[200:260, 0], axis=1)
    assert np.abs(d - 70).max() < 3.0
    free, _ = constrain(F, missing)         # not anchored: the exact fill takes half the move
    assert np.abs(free[200:260, 0] - X[200:260, 0]).max() > 2.0
    assert np.array_equal(out[~missing], X[~missing])


def test_a_trial_end_fill_keeps_to_the_observed_steps_an_interior_fill_may_exceed_them():
    """A fill held at one edge only (a gap touching a trial end) has no far edge that may need a
    fast move: its steps are shortened to the 99.9th-percentile observed step; an interior fill
    keeps steps up to 1.5 x that."""
    from torchfill.constraints import END_STEP_FACTOR, STEP_FACTOR

    X = _walk()
    missing = np.zeros(X.shape[:2], dtype=bool)
    missing[:30, 0] = True                # trial start
    missing[80:110, 3] = True             # interior
    observed = ~missing
    q999 = metrics.step_limit(X, observed, factor=1.0)
    F = X.copy()
    fast = 1.3 * q999 * np.array([1.0, 0.0, 0.0])
    F[:30, 0] = X[30, 0] - fast * np.arange(30, 0, -1)[:, None]       # 1.3 x p99.9 per frame
    F[80:95, 3] = X[79, 3] + fast * np.arange(1, 16)[:, None]         # out fast, back fast
    F[95:110, 3] = X[110, 3] + fast * np.arange(15, 0, -1)[:, None]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, report = constrain(F, missing)
    steps = lambda P, j, a, b: np.linalg.norm(np.diff(P[a:b, j], axis=0), axis=1)   # noqa: E731
    assert report.end_step_limit == pytest.approx(report.step_limit * END_STEP_FACTOR / STEP_FACTOR)
    assert steps(out, 0, 0, 31).max() <= q999 * END_STEP_FACTOR
    assert steps(F, 3, 79, 111)[1:-1].max() > 1.2 * q999          # kept: under the 1.5 x cap
    assert steps(out, 3, 79, 111).max() > 1.2 * q999
    assert np.array_equal(out[observed], X[observed])


def test_walking_hybrid_default_fill_edges_and_every_missing_sample(recording):
    """The default fill of c3dorg_s26_walking_hybrid_1_1 (trial starts with 3-5 markers seen): no
    one-frame step at a gap edge, nor anywhere in a trial-end fill, above the recording's own
    99.9th-percentile observed step; every missing sample is filled or counted in the warning
    line, which splits the trial-end samples into spatial, extrapolated in time and left NaN."""

    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_1.c3d"))
    seen = ~seq.mask & ~seq.meta["filled"]            # the file's own interpolations are not data
    q999 = metrics.step_limit(seq.points, seen, factor=1.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = torchfill.fill(seq)
    P, T = out.points, seq.n_frames
    fin = np.isfinite(P).all(axis=2)
    for j, a, b in metrics.gap_runs(seq.mask):
        path = P[max(a - 1, 0):min(b + 1, T), j]
        steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
        edge = [s for s, ok in ((steps[0], a > 0 and fin[a, j]),
                                (steps[-1], b < T and fin[b - 1, j])) if ok]
        assert all(s <= q999 * (1 + 1e-6) for s in edge), (seq.labels[j], a, b, edge)
        if a == 0 or b == T:
            assert np.nanmax(steps, initial=0) <= q999 * (1 + 1e-6), (seq.labels[j], a, b)
    (line,) = [str(w.message) for w in caught if "touch a trial end" in str(w.message)]
    spatial, time_, left = (int(x) for x in
                            re.findall(r"(\d+) (?:sample\(s\) filled|extrapolated|beyond)", line))
    assert left == int((seq.mask & ~fin).sum()) > 0
    ends = np.zeros_like(seq.mask)                   # the fill refits the file's interpolations
    for j, a, b in metrics.gap_runs(seq.mask | seq.meta["filled"]):
        ends[a:b, j] = (a == 0) != (b == T)
    donors = out.meta["fill_info"]["constraints"].rigid_done
    assert spatial + time_ + left == int((ends & ~donors).sum())


#: The recordings of the data folder with real gaps (PROVENANCE.md).
REAL_GAPPED = PLAUSIBLE_FILES


@pytest.mark.slow
@pytest.mark.parametrize("name", REAL_GAPPED)
def test_the_default_fills_nothing_outside_the_observed_volume(recording, name):
    """The default on every real gapped recording: no filled sample beyond the observed volume
    widened by the constraints' margin (the bound :func:`metrics.volume` gives)."""
    seq = torchfill.read(recording(name))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq)
    missing = seq.mask
    bounds = metrics.volume(seq.points, ~missing)
    assert metrics.outside_volume(out.points, missing, bounds) == 0
    assert np.array_equal(out.points[~missing], seq.points[~missing])


def _jacobi_reference(P, ia, ib, d0, band, share_a, share_b, iters):
    """The soft distances' Jacobi steps summed over every entry (a NaN step included)."""
    from torchfill.constraints import SOFT_WEIGHT

    P = P.copy()
    for _ in range(iters):
        diff = P[ia] - P[ib]
        n = np.sqrt((diff ** 2).sum(1))
        err = np.clip(n - d0, -band, band) - (n - d0)
        use = np.isfinite(n) & (n > 0) & (err != 0)
        if not use.any():
            break
        step = SOFT_WEIGHT * np.where(use, err / np.where(n > 0, n, 1), 0)[:, None] * diff
        C = np.zeros_like(P)
        np.add.at(C, ia, (share_a * use)[:, None] * step)
        np.subtract.at(C, ib, (share_b * use)[:, None] * step)
        count = np.bincount(ia[share_a * use > 0], minlength=len(P)) + \
            np.bincount(ib[share_b * use > 0], minlength=len(P))
        P += np.nan_to_num(C / np.maximum(count, 1)[:, None])
    return P


def test_soft_distances_step_as_a_sum_over_every_entry_with_a_nan_partner_held():
    """The projection adds the steps of the entries outside their band only: the same moves as
    the sum over every entry, where an entry beside a NaN sample holds its partner still."""
    from torchfill.constraints import SOFT_ITER, _project_distances

    rng = np.random.default_rng(3)
    T, J = 40, 5
    F = rng.normal(0.0, 100.0, (T, J, 3))
    free = rng.random((T, J)) < 0.4
    F[5, 2] = np.nan                      # a sample no fill reached, partner of free ones
    free[5, :] = True
    free[5, 2] = False
    j, k = np.triu_indices(J, 1)
    d0 = rng.uniform(50, 200, j.size)
    band = rng.uniform(1, 10, j.size)
    out = F.copy()
    _project_distances(out, free, j, k, d0, band)
    t, p = np.nonzero(free[:, j] | free[:, k])
    cells = np.unique(np.concatenate([t * J + j[p], t * J + k[p]]))
    ia, ib = np.searchsorted(cells, t * J + j[p]), np.searchsorted(cells, t * J + k[p])
    fa, fb = free[t, j[p]], free[t, k[p]]
    want = _jacobi_reference(F.reshape(-1, 3)[cells], ia, ib, d0[p], band[p],
                             np.where(fb, 0.5, 1.0) * fa, np.where(fa, 0.5, 1.0) * fb, SOFT_ITER)
    np.testing.assert_allclose(out.reshape(-1, 3)[cells], want, rtol=1e-12, atol=1e-9)
    seen = np.isfinite(F[5]).all(1)               # frame 5's samples beside the NaN stay
    assert np.array_equal(out[5][seen], F[5][seen])
    assert not np.allclose(out[free], F[free])
