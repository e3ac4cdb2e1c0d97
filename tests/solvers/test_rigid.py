"""The rigid-body fill: Kabsch against a NumPy reference, rigid pairs found in real data, and
<= 2 mm RMSE on simulated gaps of markers with >= 3 observed rigid partners."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import torchfill
from torchfill import metrics
from torchfill.segments import Segments
from torchfill.solvers import rigid
from torchfill.ops.rotation import kabsch
from torchfill.solvers.rigid import _carry_few, rigid_fill, rigid_pairs, segment_fill
from torchfill.solvers.rigid_pairs import _upper_nanquantile


#: mm: a rigid body is rebuilt exactly from positions taken to ``KEY_DECIMALS`` of the
#: recording's spread (hundreds of mm here)
EXACT = 1e-4


def _rotation(rng) -> np.ndarray:
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def test_each_sample_is_its_chosen_segments_carry_to_that_frame():
    """A truly rigid body turning fast (a random rotation a frame) in two overlapping segments:
    every sample estimated from three mates or more is exact, whichever segment is chosen (the
    chosen segment's carries are made after the choice, at its chosen samples only)."""
    rng = np.random.default_rng(3)
    T, J = 300, 8
    body = rng.normal(0, 100, (J, 3))
    turn = np.stack([_rotation(rng) for _ in range(T)])
    truth = np.einsum("tij,kj->tki", turn, body) + rng.normal(0, 500, (T, 1, 3))
    X = truth.copy()
    for _ in range(25):
        a = rng.integers(T - 30)
        X[a:a + rng.integers(3, 30), rng.integers(J)] = np.nan
    est, _, seg_of = segment_fill(X, None, {"a": list(range(6)), "b": list(range(2, 8))})
    done = np.isfinite(est).all(axis=2)
    assert done.sum() > 0.9 * np.isnan(X).any(axis=2).sum()
    assert set(np.unique(seg_of[done]).tolist()) == {0, 1}
    np.testing.assert_allclose(est[done], truth[done], rtol=0, atol=EXACT)


def test_kabsch_recovers_a_known_rotation_and_translation():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(5, 4, 3))
    Rs = np.stack([_rotation(rng) for _ in range(5)])
    t = rng.normal(size=(5, 3))
    Q = np.einsum("nkc,ndc->nkd", P, Rs) + t[:, None]
    R_hat, t_hat = kabsch(torch.from_numpy(P), torch.from_numpy(Q))
    np.testing.assert_allclose(R_hat.numpy(), Rs, atol=1e-10)
    np.testing.assert_allclose(t_hat.numpy(), t, atol=1e-10)
    assert np.allclose(np.linalg.det(R_hat.numpy()), 1.0)


def test_weighted_kabsch_ignores_points_of_weight_zero():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(3, 5, 3))
    Rs = np.stack([_rotation(rng) for _ in range(3)])
    Q = np.einsum("nkc,ndc->nkd", P, Rs) + 2.0
    Q[:, 4] += 50.0                                   # a point that moved: weight 0
    w = np.ones((3, 5))
    w[:, 4] = 0
    R_hat, t_hat = kabsch(torch.from_numpy(P), torch.from_numpy(Q), torch.from_numpy(w))
    np.testing.assert_allclose(R_hat.numpy(), Rs, atol=1e-10)
    np.testing.assert_allclose(t_hat.numpy(), 2.0, atol=1e-10)


def test_batched_kabsch_equals_a_per_frame_svd_reference_on_a_real_recording(recording,
                                                                            monkeypatch):
    """hdm05_bd_05-01: each named segment's markers carried between 2 000 random frame pairs
    with random weights (one zeroed), all pairs in one batched call across several blocks and
    mate counts: every rotation and translation equals the per-pair SVD solution (Kabsch 1976,
    with the reflection fix) to 1e-9."""
    from torchfill.ops import rotation
    from torchfill.segments import resolve
    monkeypatch.setattr(rotation, "HORN_BLOCK", 300)
    seq = torchfill.read(recording("hdm05_bd_05-01_01_120.c3d"))
    X = seq.points
    rng = np.random.default_rng(3)
    checked = 0
    for members in resolve("names", list(seq.labels)).indices(list(seq.labels)).values():
        if len(members) < 4:
            continue
        seen = np.flatnonzero(np.isfinite(X[:, members]).all(axis=(1, 2)))
        src, dst = rng.choice(seen, 2000), rng.choice(seen, 2000)
        P, Q = X[src][:, members], X[dst][:, members]
        w = rng.uniform(0.1, 1.0, size=P.shape[:2])
        w[np.arange(w.shape[0]), rng.integers(0, w.shape[1], w.shape[0])] = 0.0
        R, t = (a.numpy() for a in rotation.kabsch(*map(torch.from_numpy, (P, Q, w))))
        for n in range(0, 2000, 97):
            wn = w[n] / w[n].sum()
            cp, cq = wn @ P[n], wn @ Q[n]
            U, _, Vt = np.linalg.svd((P[n] - cp).T @ (wn[:, None] * (Q[n] - cq)))
            d = np.sign(np.linalg.det(Vt.T @ U.T))
            R_ref = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
            np.testing.assert_allclose(R[n], R_ref, atol=1e-9)
            np.testing.assert_allclose(t[n], cq - R_ref @ cp, atol=1e-9 * np.abs(X[seen]).max())
            checked += 1
    assert checked > 50


def _segment_motion(T=300, seed=0):
    """Two rigid 4-marker segments moving independently (mm), plus a free marker."""
    rng = np.random.default_rng(seed)
    time = np.arange(T) / 100.0
    out = []
    for s in range(2):
        shape = rng.normal(0, 80, size=(4, 3))
        ang = 1.5 * np.sin(2 * np.pi * (0.4 + 0.3 * s) * time)
        c, si = np.cos(ang), np.sin(ang)
        R = np.zeros((T, 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -si, si, c, 1
        trans = np.stack([500 * time, 300 * np.sin(time + s), 900 + 0 * time], 1)
        out.append(np.einsum("tcd,kd->tkc", R, shape) + trans[:, None])
    free = 400 * np.stack([np.sin(3 * time), np.cos(2 * time), time], 1)[:, None]
    return np.concatenate(out + [free], axis=1)


@pytest.mark.parametrize("T", [1, 2, 3, 7, 20, 101, 3000])
def test_upper_nanquantile_is_torch_nanquantile(T):
    g = torch.Generator().manual_seed(T)
    D = torch.rand(T, 40, generator=g, dtype=torch.float64)
    D[torch.rand(T, 40, generator=g) < 0.3] = torch.nan
    D[:, 0] = torch.nan                                       # a pair never seen together
    got, want = _upper_nanquantile(D, 0.95), torch.nanquantile(D, 0.95, dim=0)
    assert torch.equal(torch.isnan(got), torch.isnan(want))
    torch.testing.assert_close(got.nan_to_num(), want.nan_to_num(), rtol=0, atol=1e-15)


def test_rigid_pairs_are_the_segments():
    X = _segment_motion()
    pairs = rigid_pairs(X)
    seg = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2])
    expected = (seg[:, None] == seg[None]) & ~np.eye(9, dtype=bool) & (seg[:, None] < 2)
    np.testing.assert_array_equal(pairs.matrix(pairs.rigid, fill=False), expected)


def test_long_recordings_read_pair_statistics_from_evenly_spaced_frames(recording, monkeypatch):
    """Beyond ``PAIR_FRAMES`` frames the pair statistics come from every stride-th frame: on a
    real recording (hdm05_bd_05-01, 5920 frames read at every 5th) the rigid pairs found from a
    fifth of the frames are those found from all of them but for a few borderline pairs, and the
    distances agree to a fraction of the rigidity tolerance."""
    from torchfill.solvers import rigid_pairs as pairs_module

    X = torchfill.read(recording("hdm05_bd_05-01_01_120.c3d")).points
    full = rigid_pairs(X)
    monkeypatch.setattr(pairs_module, "PAIR_FRAMES", X.shape[0] // 5)
    part = rigid_pairs(X)
    assert np.array_equal(full.j, part.j) and np.array_equal(full.k, part.k)
    differ = (full.rigid != part.rigid).sum()
    assert differ <= 0.05 * full.rigid.sum()
    close = full.rigid & part.rigid
    assert np.abs(full.distance - part.distance)[close].max() < full.tol * full.scale / 4


def test_segment_fill_is_exact_on_rigid_segments_and_extrapolates():
    truth = _segment_motion()
    X = truth.copy()
    X[100:160, 0] = np.nan               # interior gap
    X[250:, 5] = np.nan                  # gap at the end: extrapolation with the segment
    X[:40, 8] = np.nan                   # the free marker: no segment, left NaN
    segments = {"a": [0, 1, 2, 3], "b": [4, 5, 6, 7]}
    est, std, seg_of = segment_fill(X, None, segments)
    done = np.isfinite(est).all(axis=2)
    assert done[100:160, 0].all() and done[250:, 5].all() and not done[:40, 8].any()
    np.testing.assert_allclose(est[done], truth[done], rtol=0, atol=EXACT)
    assert (seg_of[100:160, 0] == 0).all() and (seg_of[250:, 5] == 1).all()
    assert np.nanmax(std) < EXACT                    # rigid: the hold-out error is ~0
    out, fdone = rigid_fill(X, None, None, segments)  # the constraints' donors: the same samples
    assert np.array_equal(fdone.numpy(), done)
    seen = np.isfinite(X).all(axis=2)
    assert np.array_equal(out.numpy()[seen], X[seen])
    filled = torchfill.fill(X, "rigid", segments=segments, constraints=False)
    np.testing.assert_allclose(filled[done], truth[done], rtol=0, atol=EXACT)


def test_a_marker_seen_in_three_frames_only_is_carried_without_an_error_estimate():
    """Three frames with the marker and its mates are too few for a hold-out pair at any lag:
    the marker is still carried by its mates (exactly, on a rigid body), its error unmeasured
    (NaN), where the hold-out once failed on the empty curve."""
    truth = _segment_motion()
    X = truth.copy()
    X[3:, 0] = np.nan
    est, std, seg_of = segment_fill(X, None, {"a": [0, 1, 2, 3]})
    assert np.isfinite(est[3:, 0]).all() and np.isnan(std[3:, 0]).all()
    np.testing.assert_allclose(est[3:, 0], truth[3:, 0], rtol=0, atol=EXACT)


def test_segment_fill_kept_or_not_gives_the_same_bits_and_callers_cannot_change_the_kept(
        monkeypatch):
    """A result small enough is kept and handed out as copies; a larger one is rescaled in place
    (long recordings): the same bits either way, and a caller writing into its result (as
    rigid_fill does) changes no later answer."""
    X = _segment_motion()
    X[100:160, 0] = np.nan
    X[250:, 5] = np.nan
    X[120:130, 1] = np.nan                # a hole in a mate inside the gap: a bridged stretch
    segments = {"a": [0, 1, 2, 3], "b": [4, 5, 6, 7]}
    rigid.clear_cache()
    first = segment_fill(X, None, segments, bridge=True)
    for a in first:
        a[...] = 0                        # a caller's writes
    kept = segment_fill(X, None, segments, bridge=True)
    plain = segment_fill(X, None, segments)
    monkeypatch.setattr(rigid, "CACHE_BYTES", 0)      # too large to keep: rescaled in place
    rigid.clear_cache()
    fresh = segment_fill(X, None, segments, bridge=True)
    fresh_plain = segment_fill(X, None, segments)
    for a, b in zip(kept + plain, fresh + fresh_plain):
        assert np.array_equal(a, b, equal_nan=True)
    assert kept[3].any() and np.isnan(plain[0][kept[3]]).all()    # bridged: out without bridge
    assert (plain[2][kept[3]] == -1).all() and np.isfinite(kept[0][kept[3]]).all()


def test_segment_fill_gives_the_same_bits_on_one_thread_and_two():
    """The markers' estimates run side by side on torch's threads and are merged in the order
    of the serial loop: a marker in two segments takes the same segment's estimate either way."""
    X = _segment_motion()
    X[100:160, 0] = np.nan
    X[250:, 4] = np.nan                   # in both segments: the merge order decides
    X[40:90, 3] = np.nan
    X[120:130, 1] = np.nan
    segments = {"a": [0, 1, 2, 3, 4], "b": [3, 4, 5, 6, 7]}
    threads = torch.get_num_threads()
    results = []
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            rigid.clear_cache()
            results.append(segment_fill(X, None, segments, bridge=True))
    finally:
        torch.set_num_threads(threads)
    for a, b in zip(*results):
        assert np.array_equal(a, b, equal_nan=True)
    assert set(np.unique(results[0][2][250:, 4])) <= {0, 1} and (results[0][2][250:, 4] >= 0).all()


def test_segment_fill_a_block_of_rows_at_a_time_gives_the_same_bits(monkeypatch):
    """The batched consistency and Kabsch work of all markers goes a block of rows at a time, the
    markers a wave at a time (a long recording's peak memory does not grow with the whole batch):
    blocks of a few rows cut across the markers' requests, one marker per wave and rotations
    solved four at a time give the bits of one block over all rows."""
    from torchfill.ops import rotation
    from torchfill.solvers import rigid_batch
    X = _segment_motion()
    X[100:160, 0] = np.nan
    X[250:, 4] = np.nan
    X[40:90, 3] = np.nan
    X[120:130, 1] = np.nan
    segments = {"a": [0, 1, 2, 3, 4], "b": [3, 4, 5, 6, 7]}
    results = []
    for rows, wave, horn in ((1 << 40, 1 << 40, 1 << 40), (5, 1, 4)):
        monkeypatch.setattr(rigid_batch, "ROWS", rows)
        monkeypatch.setattr(rigid_batch, "WAVE_ROWS", wave)
        monkeypatch.setattr(rotation, "HORN_BLOCK", horn)
        rigid.clear_cache()
        results.append(segment_fill(X, None, segments, bridge=True))
    for a, b in zip(*results):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.isfinite(results[0][0][100:160, 0]).all()


def test_segment_fill_with_no_segment_to_fit_and_with_twin_segments():
    """Segments of three markers leave every sample to other models (no marker to estimate);
    two segments with the same members give the first segment's estimate, the same bits as that
    segment alone."""
    X = _segment_motion()
    X[100:160, 0] = np.nan
    est, std, seg_of = segment_fill(X, None, {"a": [0, 1, 2], "b": [4, 5, 6]})
    assert np.isnan(est).all() and np.isnan(std).all() and (seg_of == -1).all()
    alone = segment_fill(X, None, {"a": [0, 1, 2, 3]})
    twins = segment_fill(X, None, {"a": [0, 1, 2, 3], "b": [3, 2, 1, 0]})
    for a, b in zip(alone, twins):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.isfinite(alone[0][100:160, 0]).all()


def test_one_mate_is_left_to_other_models_and_the_method_says_which_markers():
    truth = _segment_motion()
    X = truth.copy()
    X[100:160, :3] = np.nan              # three of four missing: one mate left
    est, _, _ = segment_fill(X, None, {"a": [0, 1, 2, 3]})
    assert np.isnan(est[100:160, :3]).all()
    with pytest.warns(UserWarning, match=r"180 of 180 missing samples .* PCHIP; markers "
                                         r"\(samples\): 0 \(60\), 1 \(60\), 2 \(60\)"):
        torchfill.fill(X, "rigid", segments={"a": [0, 1, 2, 3]}, constraints=False)


def _foot_gaps(recording, name):
    """RTOE missing over 60 frames at several places of a real recording, RMT5 over those frames
    and 5 more on each side: two foot mates (RANK, RHEE) seen in the gap, three at its edges."""
    seq = torchfill.read(recording(name))
    labels = [str(x).rpartition(":")[2] for x in seq.labels]
    j, k = labels.index("RTOE"), labels.index("RMT5")
    mask = np.zeros(seq.points.shape[:2], dtype=bool)
    for start in range(200, seq.n_frames - 200, 400):
        mask[start:start + 60, j] = True
        mask[start - 5:start + 65, k] = True
    return seq, mask, j


def test_two_mates_carry_a_gap_from_both_edges_with_their_own_error(recording):
    """hdm05_bd_05-01 (Plug-in Gait, 120 Hz): a toe marker whose gaps leave two foot mates seen
    is filled there from both observed edges (no step at either edge), within a few mm, with an
    error estimate of the size of the error; like a bridge they are the rigid method's alone
    (not donors, not the default's candidate), observed samples stay bit-identical."""
    seq, mask, j = _foot_gaps(recording, "hdm05_bd_05-01_01_120.c3d")
    truth = seq.points
    gappy = np.where(mask[..., None], np.nan, truth)
    est, std, seg_of, bridged = segment_fill(gappy, None, "names", seq.labels, bridge=True)
    gap = mask[:, j]
    assert np.isfinite(est[gap, j]).all() and (seg_of[gap, j] >= 0).all()
    assert bridged[gap, j].all()
    assert np.isnan(segment_fill(gappy, None, "names", seq.labels)[0][gap, j]).all()
    err = np.linalg.norm(est[gap, j] - truth[gap, j], axis=1)
    rmse = np.sqrt(np.mean(err ** 2))
    assert rmse < 5.0
    assert 0.5 * rmse < np.sqrt(3 * np.mean(std[gap, j] ** 2)) < 10 * rmse
    steps = np.linalg.norm(np.diff(truth[:, j], axis=0), axis=1)
    filled = np.where(gap[:, None], est[:, j], truth[:, j])
    edge = np.flatnonzero(np.diff(gap.astype(int)) != 0)   # the steps into and out of each gap
    assert (np.linalg.norm(filled[edge + 1] - filled[edge], axis=1)
            <= 3 * np.percentile(steps, 99) + 1.0).all()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq.with_points(gappy), "rigid", segments="names",
                             constraints=False).points
    assert np.array_equal(out[~mask], truth[~mask])
    np.testing.assert_allclose(out[gap, j], est[gap, j], atol=1e-6)   # the rigid method's fill


@pytest.mark.parametrize("name", ["HDM_bd_01-02_01_120.c3d", "hdm05_mm_01-02_03_120.c3d"])
def test_rigid_method_within_a_few_mm_where_three_mates_are_seen(recording, name):
    """One 120-frame gap in each of several markers of different named segments: where three
    mates are seen, the rigid fill is within 5 mm RMS (skin markers) and far better than PCHIP."""
    seq = torchfill.read(recording(name))
    seq = seq.select([j for j, lab in enumerate(seq.labels) if not lab.startswith("*")])
    truth = seq.points
    T, J = truth.shape[:2]
    seg = Segments.from_names(seq.labels).indices(seq.labels)
    chosen = [m[0] for m in seg.values() if len(m) >= 4][:6]
    rng = np.random.default_rng(0)
    mask = np.zeros((T, J), dtype=bool)
    for j in chosen:
        start = rng.integers(0, T - 120)
        mask[start:start + 120, j] = True
    gappy = seq.with_points(np.where(mask[..., None], np.nan, truth))
    filled = torchfill.fill(gappy, "rigid", constraints=False).points
    assert np.array_equal(filled[~mask], truth[~mask])
    est, _, _ = segment_fill(gappy.points, None, None, seq.labels)
    done = np.isfinite(est).all(axis=2) & mask
    assert done.sum() >= 0.9 * mask.sum()
    assert metrics.rmse_missing(filled, truth, done) <= 5.0
    assert metrics.rmse_missing(filled, truth, done) < 0.5 * metrics.rmse_missing(
        torchfill.fill(gappy.points, "pchip", constraints=False), truth, done)


def test_a_ghost_in_a_mates_track_does_not_steer_the_fit():
    """A mate whose label jumps to a still point 1.8 m away for the last third of the trial (a
    swap onto a ghost, as in the hockey recording's LFHD) is down-weighted where its distances to
    the other mates leave their band: the trial-end fill from the three good mates stays exact."""
    T = 300
    time = np.arange(T) / 100.0
    shape = np.random.default_rng(1).normal(0, 80, size=(5, 3))
    ang = 1.5 * np.sin(2 * np.pi * 0.4 * time)
    c, s = np.cos(ang), np.sin(ang)
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1
    trans = np.stack([500 * time, 300 * np.sin(time), 900 + 0 * time], 1)
    truth = np.einsum("tcd,kd->tkc", R, shape) + trans[:, None]
    X = truth.copy()
    X[200:, 1] = truth[200, 1] + [1800.0, 0.0, 0.0]      # the ghost: still, far away
    X[220:, 0] = np.nan
    est, _, _ = segment_fill(X, None, {"a": [0, 1, 2, 3, 4]})
    err = np.linalg.norm(est[220:, 0] - truth[220:, 0], axis=1)
    assert err.max() < 0.1


def test_rigid_fill_does_not_jump_where_a_mate_is_the_files_own_fill(recording):
    """walking_hybrid_1_4's R_SHANK_3 gap (frames 287..375): R_SHANK_4 and R_SHANK_1 are the
    file's own earlier fill over parts of it, so only one or two mates are observed there; the
    fill carries on with them rather than switching models mid-gap (it jumped 32 mm at 315)."""
    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_4.c3d"))
    k = list(seq.labels).index("R_SHANK_3")
    assert seq.mask[287:376, k].all() and not seq.mask[[286, 376], k].any()
    with pytest.warns(UserWarning):
        out = torchfill.fill(seq, method="rigid")
    steps = metrics.norm_last(np.diff(out.points[286:377, k], axis=0))
    observed = metrics.observed_steps(seq.points[:, k:k + 1], ~seq.mask[:, k:k + 1])
    assert np.isfinite(steps).all()
    assert steps.max() < 1.5 * observed.max()
    assert np.array_equal(out.points[~seq.mask], seq.points[~seq.mask])


def test_carry_with_fewer_than_three_mates():
    """Two mates: exact for a turn about an axis across their line (the smallest rotation), and
    the line's end points carried onto themselves; one mate: its shift; none: unmoved."""
    rng = np.random.default_rng(3)
    P = rng.normal(size=(3, 4, 3))
    x = rng.normal(size=(3, 3))
    u = P[0, 1] - P[0, 0]
    axis = np.cross(u, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(0.7) * K + (1 - np.cos(0.7)) * K @ K
    Q = P @ R.T + np.array([1.0, -2.0, 0.5])
    S = np.zeros((3, 4), dtype=bool)
    S[0, :2] = True
    S[1, 2] = True
    out = rigid._drive([_carry_few(P, Q, S, x, np.ones(4))])[0]     # a generator of requests
    np.testing.assert_allclose(out[0], R @ x[0] + np.array([1.0, -2.0, 0.5]), atol=1e-12)
    np.testing.assert_allclose(out[1], x[1] + Q[1, 2] - P[1, 2], atol=1e-12)
    np.testing.assert_array_equal(out[2], x[2])


def test_a_hole_in_the_mates_inside_a_gap_is_carried_by_the_mates_left():
    """Marker 0 missing over 100..159 and mate 1 over 120..139 (two mates left there): without
    ``bridge`` those frames stay NaN, as before; with it they are carried from both sides by
    markers 2 and 3, within a few mm of the truth and without a step beyond the marker's own;
    the rigid method fills them so (the default's donors and candidate leave them out)."""
    truth = _segment_motion()
    X = truth.copy()
    X[100:160, 0] = np.nan
    X[120:140, 1] = np.nan
    seg = {"a": [0, 1, 2, 3]}
    est, _, _ = segment_fill(X, None, seg)
    assert np.isnan(est[120:140, 0]).all() and np.isfinite(est[100:120, 0]).all()
    est, std, _, bridged = segment_fill(X, None, seg, bridge=True)
    assert np.array_equal(np.flatnonzero(bridged[:, 0]), np.arange(120, 140))
    assert np.array_equal(np.flatnonzero(bridged[:, 1]), np.arange(120, 140))   # two mates
    assert not bridged[:, 2:].any()
    err = metrics.norm_last(est[120:140, 0] - truth[120:140, 0])
    assert err.max() < 5.0 and (np.sqrt(3.0) * std[120:140, 0] >= err).all()
    with warnings.catch_warnings(record=True) as caught:    # marker 1's own gap: two mates
        warnings.simplefilter("always")                     # seen throughout, a two-mate fill
        filled = torchfill.fill(X, "rigid", segments=seg, constraints=False)
    assert not [w for w in caught if "rigid:" in str(w.message)]
    assert np.isfinite(est[120:140, 1]).all()
    steps = metrics.norm_last(np.diff(filled[99:161, 0], axis=0))
    assert steps.max() < 1.5 * metrics.observed_steps(X[:, :1], np.isfinite(X[:, :1, 0])).max()
    np.testing.assert_allclose(filled[120:140, 0], est[120:140, 0], rtol=0, atol=1e-9)


def test_the_default_fills_the_same_bits_whatever_filled_the_recording_before(recording):
    """The rigid reconstruction is kept for the same recording in any units (the data's, a
    solver's normalized ones): what is kept must not depend on which of them came first. On a
    real gapped recording the default's fill and error estimate are the same bit for bit with or
    without a ``rigid`` fill (which asks in its own units) before it in the process."""
    from torchfill.runtime.cache import clear_all

    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_1.c3d"))
    runs = []
    for before in ((), ("rigid",)):
        clear_all()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for method in before:
                torchfill.fill(seq, method)
            out, std = torchfill.fill(seq, return_std=True)
        runs.append((out.points, np.asarray(std)))
    (a, sa), (b, sb) = runs
    assert np.array_equal(a, b, equal_nan=True) and np.array_equal(sa, sb, equal_nan=True)
