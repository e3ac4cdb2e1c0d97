"""Segments from marker names, from the data and from a user's YAML; the rigid reconstruction from
segment-mates on real recordings with real gap masks; memory that grows linearly with markers."""
from __future__ import annotations

import tracemalloc
import warnings

import numpy as np
import pytest

import torchfill
from torchfill import gaps
from torchfill.segments import Segments, agreement, load, parse, purity, resolve
from torchfill.solvers.rigid import rigid_pairs, segment_fill


def _short(members):
    return sorted(m.rpartition(":")[2] for m in members)


def test_segments_from_plug_in_gait_names_with_a_subject_prefix(recording):
    seq = torchfill.read(recording("biomechzoo_hockey_wrist_shot_009.c3d"))
    seg = Segments.from_names(seq.labels)
    assert _short(seg["head"]) == ["LBHD", "LFHD", "RBHD", "RFHD"]
    assert _short(seg["pelvis"]) == ["LASI", "LPSI", "RASI", "RPSI"]
    assert _short(seg["l_forearm"]) == ["LELB", "LFRA", "LWRA", "LWRB"]
    assert not any("Stick" in m for members in seg.values() for m in members)


@pytest.mark.parametrize("name,segment,members", [
    ("osim_gait2392_subject01_walk1.trc", "r_thigh", ["R.Thigh.Front", "R.Thigh.Rear",
                                                      "R.Thigh.Upper"]),
    ("osim_rajagopal_motion_capture_walk.trc", "l_shank", ["L.Ankle", "L.Knee", "L.SH1", "L.SH2",
                                                           "L.SH3"]),
    ("hdm05_bd_05-01_01_120.c3d", "r_foot", ["RANK", "RHEE", "RMT5", "RTOE"]),
    ("cmu_135_02.c3d", "pelvis", ["LBWT", "LFWT", "RBWT", "RFWT"]),
    ("c3dorg_s26_walking_hybrid_1_1.c3d", "l_thigh", ["L_THIGH_1", "L_THIGH_2", "L_THIGH_3",
                                                      "L_THIGH_4"]),
])
def test_segments_from_the_names_of_real_marker_sets(recording, name, segment, members):
    seq = torchfill.read(recording(name))
    seg = Segments.from_names(seq.labels)
    assert _short(seg[segment]) == sorted(members)
    covered = {m for ms in seg.values() for m in ms}
    assert len(covered) >= 0.9 * seq.n_markers        # the tables know these marker sets


def test_two_subjects_get_their_own_segments(recording):
    seq = torchfill.read(recording("ktk_tennis_serve_2players.c3d"))
    seg = Segments.from_names(seq.labels)
    assert _short(seg["Derrick:head"]) == _short(seg["Viktor:head"])
    assert all(m.startswith("Viktor:") for m in seg["Viktor:pelvis"])
    idx = seg.indices(seq.labels)
    assert set(idx["Derrick:pelvis"]).isdisjoint(idx["Viktor:pelvis"])


def test_every_stick_marker_gets_a_segment_from_the_data(recording):
    """biomechZoo hockey: the Plug-in Gait tables name no segment for the stick's ten markers and
    the puck's two; a fill's segments (names, then the data for the markers they leave out) give
    every marker a segment and every stick marker three mates or more, all of them stick
    markers, keep the named segments as they are, and print each one's source; on CMU 135_02
    (every marker named) they are the tables alone."""
    seq = torchfill.read(recording("biomechzoo_hockey_wrist_shot_009.c3d"))
    named = Segments.from_names(seq.labels)
    seg = resolve(None, seq.labels, seq.points, ~seq.mask)
    assert seg.source == "names+data" and all(seg[s] == m for s, m in named.items())
    idx = seg.indices(seq.labels)
    for j, label in enumerate(seq.labels):
        assert any(j in m for m in idx.values()), label
        if label.startswith("Stick:"):
            mine = [s for s, m in idx.items() if j in m and len(m) >= 4]
            assert mine and all(seg.sources[s] == "data" and s.startswith("data:") for s in mine)
            assert all(seq.labels[k].startswith("Stick:") for s in mine for k in idx[s])
    text = seg.to_yaml()
    assert '"head": ["Reed:LFHD", "Reed:RFHD", "Reed:LBHD", "Reed:RBHD"]  # names' in text
    assert sum(line.endswith("# data") and '"Stick:' in line for line in text.splitlines()) >= 10
    assert list(parse(text).items()) == list(seg.items())
    cmu = torchfill.read(recording("cmu_135_02.c3d"))
    assert resolve(None, cmu.labels, cmu.points, ~cmu.mask) == Segments.from_names(cmu.labels)


def test_yaml_round_trip_and_bad_files(tmp_path, recording):
    seq = torchfill.read(recording("biomechzoo_hockey_wrist_shot_009.c3d"))
    seg = Segments.from_names(seq.labels)
    path = tmp_path / "seg.yaml"
    path.write_text(seg.to_yaml())
    back = load(path)
    assert list(back.items()) == list(seg.items())
    assert resolve(str(path), seq.labels) == seg
    odd = Segments({'a "b": c': ["x: y", "it's"]})
    assert parse(odd.to_yaml()) == odd
    bad = tmp_path / "bad.yaml"
    bad.write_text("pelvis: LASI\n")
    with pytest.raises(ValueError, match="bad.yaml.*list of marker labels"):
        load(bad)
    with pytest.raises(ValueError, match="missing.yaml"):
        load(tmp_path / "missing.yaml")


def test_user_segments_match_labels_without_prefix_and_case(recording):
    seq = torchfill.read(recording("biomechzoo_hockey_wrist_shot_009.c3d"))
    idx = Segments({"pelvis": ["lasi", "RASI", "l.psi", "Reed:RPSI"]}).indices(seq.labels)
    assert [seq.labels[j] for j in idx["pelvis"]] == ["Reed:LASI", "Reed:RASI", "Reed:LPSI",
                                                     "Reed:RPSI"]


@pytest.mark.parametrize("name", [
    "biomechzoo_hockey_wrist_shot_009.c3d", "osim_gait2392_subject01_walk1.trc",
    "osim_hamner_subject02_running.trc", "osim_rajagopal_motion_capture_run.trc",
    "osim_rajagopal_motion_capture_walk.trc", "hdm05_bd_05-01_01_120.c3d",
    "hdm05_mm_01-02_03_120.c3d", "HDM_bd_01-02_01_120.c3d", "hdm05_dg_06-03_03_120.c3d",
    "cmu_135_02.c3d", "cmu_02_01.c3d", "cmu_85_02.c3d", "cmu_85_12.c3d"])
def test_segments_found_in_the_data_agree_with_the_tables(recording, name):
    """Labels hidden, the near-rigid clusters reproduce >= 90 % of the named memberships (measured
    91.9-100 %; cmu_02_01, a 3 s walk whose left elbow the cut folds into the forearm, 94.9 %
    with that pair's own segment), and >= 80 % of their own memberships lie in the matched named
    segment (measured 84-100 %)."""
    seq = torchfill.read(recording(name))
    keep = [j for j in range(seq.n_markers) if np.isfinite(seq.points[:, j]).all()
            and not seq.labels[j].startswith("*")]
    seq = seq.select(keep)
    found = Segments.from_data(seq.points)                 # the labels never reach the clusters
    found = Segments({s: [seq.labels[int(j)] for j in m] for s, m in found.items()})
    named = Segments.from_names(seq.labels)
    assert agreement(found, named, seq.labels) >= 0.9
    assert purity(found, named, seq.labels) >= 0.8


def _two_bodies(T=400, seed=0):
    """Two rigid bodies of four markers hinged at the origin, a fifth marker on the hinge axis,
    1 mm noise: the thigh, the shank and the knee marker."""
    rng = np.random.default_rng(seed)
    A = rng.normal(0, 60, (4, 3)) + [0, 0, 250]
    B = rng.normal(0, 60, (4, 3)) + [0, 0, -250]
    knee = np.array([[0.0, 40.0, 0.0]])                         # on the hinge axis (y)
    q = 0.8 * np.sin(np.linspace(0, 6 * np.pi, T))
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 2], R[:, 2, 0], R[:, 2, 2], R[:, 1, 1] = (np.cos(q), np.sin(q),
                                                                   -np.sin(q), np.cos(q), 1)
    X = np.concatenate([np.broadcast_to(A, (T, 4, 3)), np.einsum("tij,kj->tki", R, B),
                        np.broadcast_to(knee, (T, 1, 3))], axis=1)
    return X + rng.normal(0, 1.0, X.shape) + np.linspace(0, 800, T)[:, None, None] * [1, 0, 0]


def test_data_segments_are_the_rigid_bodies_with_the_hinge_marker_in_both_in_any_units():
    X = _two_bodies()
    found = Segments.from_data(X)
    assert sorted(found.values()) == [["0", "1", "2", "3", "8"], ["4", "5", "6", "7", "8"]]
    assert Segments.from_data(X / 1000.0) == found             # metres: the same clusters
    X[50:90, 2] = np.nan
    X[200:260, 5] = np.nan
    gappy = Segments.from_data(X)                              # gaps: within the bodies still
    A, B = {"0", "1", "2", "3", "8"}, {"4", "5", "6", "7", "8"}
    assert all(set(m) <= A or set(m) <= B for m in gappy.values())
    assert set().union(*gappy.values()) == A | B
    assert any(set(m) <= A and "8" in m for m in gappy.values())
    assert any(set(m) <= B and "8" in m for m in gappy.values())


def test_a_fill_finds_no_segments_on_a_dense_surface_unless_asked():
    """Above DENSE points the default takes none (the rigid pairs serve a dense surface);
    ``segments="data"`` still finds the bodies."""
    from torchfill.segments import DENSE
    X = np.concatenate([_two_bodies(T=120, seed=s) for s in range(DENSE // 9 + 1)], axis=1)
    assert X.shape[1] > DENSE
    assert len(resolve(None, None, X)) == 0
    assert len(resolve("data", None, X)) >= 2 * (DENSE // 9 + 1)


def _case(recording, target, source):
    truth = torchfill.read(recording(target))
    keep = [j for j in range(truth.n_markers) if np.isfinite(truth.points[:, j]).all()]
    truth = truth.select(keep)
    src = torchfill.read(recording(source))
    S = ~np.isfinite(src.points).all(axis=2)
    ratio = truth.rate / src.rate
    T = min(truth.n_frames, int(S.shape[0] * ratio))
    truth = truth.with_points(truth.points[:T])
    mask = gaps.transplant(S, T, truth.n_markers, seed=0, rate_ratio=ratio)
    return truth, mask


def test_rigid_on_a_real_mask_is_as_good_as_gapfill_and_keeps_observed_samples(recording):
    """biomechZoo hockey (Plug-in Gait) with the real gaps of walking_hybrid_1_1 laid on it:
    on the samples gapfill's recover_marker_rbt fills with the same named segments, the rigid
    method's RMSE is at most gapfill's; observed samples are returned bit-identical."""
    pytest.importorskip("gapfill")                      # the peer must be there
    from benchmarks import peers

    truth, mask = _case(recording, "biomechzoo_hockey_wrist_shot_009.c3d",
                        "c3dorg_s26_walking_hybrid_1_1.c3d")
    P = truth.points.copy()
    P[mask] = np.nan
    seq = truth.with_points(P)
    GF = peers.fill("gapfill", seq)                      # named segments, as rigid's
    on = np.isfinite(GF).all(axis=2) & mask
    assert on.sum() > 50
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq, "rigid", constraints=False).points
    assert np.array_equal(out[~mask], truth.points[~mask])

    def rmse(F):
        return np.sqrt(np.mean(np.sum((F[on] - truth.points[on]) ** 2, axis=1)))
    assert rmse(out) <= rmse(GF)


def test_segment_fill_leaves_samples_without_three_mates_and_estimates_its_error(recording):
    truth, mask = _case(recording, "hdm05_bd_05-01_01_120.c3d", "c3dorg_s26_walking_hybrid_1_5.c3d")
    P = np.where(mask[..., None], np.nan, truth.points)
    est, std, seg_of = segment_fill(P, None, None, truth.labels)
    done = np.isfinite(est).all(axis=2)
    assert not done[~mask].any() and (seg_of[done] >= 0).all() and (seg_of[~done] == -1).all()
    assert np.isfinite(std[done]).all() and np.isnan(std[~done]).all()
    seg = resolve(None, truth.labels, P).indices(truth.labels)     # the tables and the data
    seen = ~mask
    for t, j in zip(*np.nonzero(done)):                   # >= 3 mates of one segment seen there
        assert any(j in m and seen[t, [k for k in m if k != j]].sum() >= 3 for m in seg.values())
    err = np.linalg.norm(est[done] - truth.points[done], axis=1)
    big = std[done] > np.median(std[done])                # larger estimates, larger errors
    assert np.sqrt(np.mean(err[big] ** 2)) > np.sqrt(np.mean(err[~big] ** 2))


def test_rigid_pairs_memory_grows_linearly_with_markers():
    """6 000 points: all pairs would need (J, J) arrays of 288 MB each (1.4 GB for the five the
    pair statistics kept); near neighbours only stay far below."""
    rng = np.random.default_rng(0)
    T, J = 40, 6000
    base = rng.normal(0, 500, (J, 3))
    X = base[None] + rng.normal(0, 1, (T, J, 3)) + np.linspace(0, 100, T)[:, None, None]
    X[rng.random((T, J)) < 0.05] = np.nan
    tracemalloc.start()
    pairs = rigid_pairs(X)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert pairs.j.size <= 12 * J                      # neighbours only
    assert peak < 150e6


@pytest.mark.parametrize("T", [1, 2, 3, 7, 50])
def test_column_quantiles_are_numpys_nanquantile(T):
    from torchfill.segments import _col_quantile
    rng = np.random.default_rng(T)
    D = rng.random((T, 30))
    D[rng.random((T, 30)) < 0.3] = np.nan
    D[:, 0] = np.nan                                       # a pair never seen together
    n = np.isfinite(D).sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for q in (0.5, 0.95):
            np.testing.assert_allclose(_col_quantile(np.sort(D, axis=0), n, q),
                                       np.nanquantile(D, q, axis=0), rtol=0, atol=1e-15)
            np.testing.assert_allclose(                  # a map's quantile from two values a column
                _col_quantile(np.sort(-D, axis=0), n, q, lambda x: np.arccos(-x)),
                np.nanquantile(np.arccos(D), q, axis=0), rtol=0, atol=1e-15)
