"""``auto``: per-gap choice of methods from hold-outs of observed data, and its error estimate.

On real recordings with simulated gaps (skipped without ../shared/data): auto is never much worse
than the best of its candidates, and the error estimate is calibrated (real 3-D error within
2 sqrt(3) std for most filled samples, per-gap ranking). Every input kind returns (filled, std).
"""
from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
import torch
from scipy.stats import spearmanr

import torchfill
from torchfill import gaps
from torchfill.cli import main
from torchfill.metrics import gap_runs, rmse, rmse_missing
from torchfill.solvers import get_solver
from torchfill.solvers.selection.candidates import Fits
from torchfill.solvers.selection.draws import MAX_DRAWS
from torchfill.solvers.selection.kinds import gap_kind, run_geometry
from torchfill.solvers.selection.weights import consensus, kind_weights

CANDIDATES = ("pchip", "pca_train", "svt", "tucker_tnn")


def _walk(T=150, J=6, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 3, T)[:, None, None]
    phase = rng.uniform(0, 2 * np.pi, size=(1, J, 3))
    return 500 + 100 * np.sin(2 * np.pi * t + phase) + 30 * np.cos(5 * t + phase)


def _gappy():
    X = _walk()
    X[40:70, 1] = np.nan
    X[100:110, 3] = np.nan
    X[:12, 4] = np.nan
    return X


def _real(recording, name, frames=None):
    P = torchfill.read(recording(name)).points
    P = P[:frames] if frames else P
    return P[:, np.isfinite(P).all(axis=2).all(axis=0)]


def test_run_geometry_distance_length_and_trial_end():
    missing = torch.zeros(12, 2, dtype=torch.bool)
    missing[3:8, 0] = True                    # interior gap of 5
    missing[9:, 1] = True                     # gap at the end, 3 frames
    d, L, edge = run_geometry(missing)
    assert d[3:8, 0].tolist() == [1, 2, 3, 2, 1]
    assert L[3:8, 0].tolist() == [5] * 5 and L[9:, 1].tolist() == [3] * 3
    assert d[9:, 1].tolist() == [1, 2, 3]     # one observed side only
    assert not bool(edge[:, 0].any()) and bool(edge[9:, 1].all())
    assert int(d[~missing].abs().sum()) == 0 and not bool(edge[~missing].any())
    kind = gap_kind(L, edge, torch.zeros_like(edge))
    assert kind[9, 1] % 2 == 1 and kind[3, 0] % 2 == 0


@pytest.mark.parametrize("kind", ["array", "tensor", "sequence"])
def test_return_std_for_every_input_kind(kind):
    X = _gappy()
    missing = np.isnan(X).any(axis=2)
    data = {"array": X, "tensor": torch.from_numpy(X),
            "sequence": torchfill.MarkerSequence(points=X, labels=[f"M{j}" for j in range(6)],
                                                 rate=100.0, units="mm")}[kind]
    out, std = torchfill.fill(data, method="auto", return_std=True, candidates=["pchip", "svt"])
    std = std.numpy() if kind == "tensor" else std
    points = out.points if kind == "sequence" else np.asarray(out)
    assert std.shape == missing.shape
    assert np.isnan(std[~missing]).all() and np.isfinite(std[missing]).all() and (std[missing] > 0).all()
    np.testing.assert_array_equal(points[~missing], X[~missing])     # observed unchanged
    if kind == "sequence":
        np.testing.assert_array_equal(out.meta["std"], std, strict=True)


def test_return_std_for_a_method_without_its_own():
    X = _gappy()
    missing = np.isnan(X).any(axis=2)
    plain = torchfill.fill(X, method="pchip")
    out, std = torchfill.fill(X, method="pchip", return_std=True)
    np.testing.assert_array_equal(out, plain)                         # the fill is the method's
    assert np.isfinite(std[missing]).all() and np.isnan(std[~missing]).all()


def test_cli_writes_std_csv(tmp_path):
    X = _gappy()
    path = tmp_path / "trial.npz"
    np.savez(path, points=X, labels=np.array([f"M{j}" for j in range(6)]), rate=100.0, units="mm")
    out, std_path, report = tmp_path / "filled.npz", tmp_path / "std.csv", tmp_path / "qc.html"
    assert main(["fill", str(path), "-o", str(out), "-m", "auto", "-q", "--std", str(std_path),
                 "--report", str(report), "-p", 'candidates=["pchip","svt"]']) == 0
    assert ">est. RMS error (mm)</th>" in report.read_text()     # the qc report shows it per gap
    table = np.genfromtxt(std_path, delimiter=",", names=True)
    assert table.dtype.names[0] == "frame" and len(table) == X.shape[0]
    S = np.column_stack([table[n] for n in table.dtype.names[1:]])
    missing = np.isnan(X).any(axis=2)
    assert np.isfinite(S[missing]).all() and np.isnan(S[~missing]).all()


def test_the_pma_family_averages_its_hold_out_fit_and_refit_on_trial_end_kinds(monkeypatch):
    """On the samples of the trial-end kinds a candidate of ``END_AVERAGE`` keeps the mean of its
    hold-out fill and its refit (two fills from different observed samples; their trial-end
    fills swing either way); inside, and for the other candidates, the refit replaces it."""
    T, J = 20, 3
    M = torch.zeros(T, J, 3, dtype=torch.float64)
    gaps = torch.zeros(T, J, dtype=torch.bool)
    gaps[:5, 0] = gaps[8:12, 1] = True                    # one at the trial start, one inside
    end = torch.zeros_like(gaps)
    end[:5, 0] = True
    fits = Fits(M, torch.zeros(3, dtype=torch.float64), torch.ones((), dtype=torch.float64), {},
                0, None, None, {}, lambda r: None)
    names = ["pma", "li", "lgrnn", "pchip"]
    held = torch.stack([torch.full((T, J, 3), float(c + 1), dtype=torch.float64)
                        for c in range(len(names))])
    monkeypatch.setattr(Fits, "fit_all", lambda self, names, *a, then, **k: [
        then(name, torch.full((T, J, 3), 10.0 * (c + 1), dtype=torch.float64))
        for c, name in enumerate(names)])
    out, _ = fits.refit(names, held, torch.ones(len(names), T, J, dtype=torch.float64), gaps, end)
    for c, name in enumerate(names):
        refit, kept = 10.0 * (c + 1), float(c + 1)
        at_end = (refit + kept) / 2 if name in ("pma", "li", "lgrnn") else refit
        assert torch.all(out[c][end] == at_end), name
        assert torch.all(out[c][gaps & ~end] == refit), name
        assert torch.all(out[c][~gaps] == kept), name


def test_progress_reports_every_candidate_fit_and_refit():
    """auto's one step takes as long as all its candidates: the callback hears of each fit."""
    seen = []
    solver = get_solver("auto", candidates=["pchip", "spline", "svt"])
    solver.fit(torch.from_numpy(_gappy()), callback=seen.append)
    fits = [r["fit"] for r in seen if "fit" in r]
    refits = [r["refit"] for r in seen if "refit" in r]
    assert fits == [1.0, 2.0, 3.0] and all(r["fits"] == 3.0 for r in seen if "fit" in r)
    assert refits == [float(k) for k in range(1, len(refits) + 1)] and refits
    assert all(r["iter"] == 1 for r in seen) and "delta" in seen[-1]   # the step's record last
    assert len(solver.history_) == 1 and solver.callback_ is None         # reports not kept


def test_a_second_draw_holds_out_other_observed_samples(monkeypatch):
    """The weights pool two hold-out draws (which shift one draw takes moves single cases by
    20-30 %): each hides the real gaps and observed samples of its own, not the first's."""
    X = _gappy()
    solver = get_solver("auto", candidates=["pchip", "spline", "svt"], min_gaps=0)
    hidden, fit_all = [], Fits.fit_all

    def spy(self, names, fit_missing, stage="fit", case=None, **kw):
        hidden.append((stage, fit_missing.clone()))
        return fit_all(self, names, fit_missing, stage, case, **kw)
    monkeypatch.setattr(Fits, "fit_all", spy)
    solver.fit(torch.from_numpy(X))
    missing = torch.from_numpy(np.isnan(X).any(axis=2))
    held = [m & ~missing for stage, m in hidden if stage in ("fit", "draw")]
    assert [stage for stage, _ in hidden] == ["fit", "draw", "refit"]
    assert all(bool(m[missing].all()) for _, m in hidden)
    assert all(bool(h.any()) for h in held) and not torch.equal(*held)


@pytest.mark.parametrize("min_gaps, draws", [(0, 2), (6, 2), (40, MAX_DRAWS)])
def test_a_recording_with_few_gaps_gets_more_draws(min_gaps, draws, monkeypatch):
    """A draw of a recording with few gaps holds out few (``_gappy``: three real gaps, three to
    four held out per draw), and which ones decides the weights: the draws go on, up to
    MAX_DRAWS, until ``min_gaps`` held-out gaps are pooled."""
    solver = get_solver("auto", candidates=["pchip", "spline"], min_gaps=min_gaps)
    stages, fit_all = [], Fits.fit_all

    def spy(self, names, fit_missing, stage="fit", case=None, **kw):
        stages.append(stage)
        return fit_all(self, names, fit_missing, stage, case, **kw)
    monkeypatch.setattr(Fits, "fit_all", spy)
    solver.fit(torch.from_numpy(_gappy()))
    assert stages.count("fit") + stages.count("draw") == draws


def test_one_draw_where_its_held_out_gaps_are_many_distinct_windows(monkeypatch):
    """Thirty short gaps, each at its own time: the first draw holds out thirty distinct
    windows, enough alone; forty-eight gaps in four shared windows (twelve markers hidden
    together) are four events, and draw again."""
    def count(X):
        solver = get_solver("auto", candidates=["pchip", "spline"])
        stages, fit_all = [], Fits.fit_all

        def spy(self, names, fit_missing, stage="fit", case=None, **kw):
            stages.append(stage)
            return fit_all(self, names, fit_missing, stage, case, **kw)
        monkeypatch.setattr(Fits, "fit_all", spy)
        solver.fit(torch.from_numpy(X))
        monkeypatch.undo()
        return stages.count("fit") + stages.count("draw")

    apart, shared = _walk(T=600, J=12), _walk(T=600, J=12)
    for k in range(30):
        apart[40 + 17 * k:45 + 17 * k, k % 12] = np.nan
    for a in (60, 200, 340, 480):
        shared[a:a + 30] = np.nan
        shared[a:a + 30, 0] = _walk(T=600, J=12)[a:a + 30, 0]     # one marker seen throughout
    assert count(apart) == 1 and count(shared) > 1


def test_the_extra_draws_for_few_gaps_leave_tucker_tnn_out(monkeypatch):
    """A recording with few gaps draws again until ``min_gaps`` held-out gaps are pooled; those
    extra draws (beyond ``draws``) fit the cheap candidates only: ``tucker_tnn``, most of the
    fits' time, is scored on the first ``draws`` draws."""
    solver = get_solver("auto", candidates=["pchip", "tucker_tnn"])
    stages, fit_all = [], Fits.fit_all

    def spy(self, names, fit_missing, stage="fit", case=None, **kw):
        stages.append((stage, list(names)))
        return fit_all(self, names, fit_missing, stage, case, **kw)
    monkeypatch.setattr(Fits, "fit_all", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver.fit(torch.from_numpy(_gappy()))
    draws = [names for stage, names in stages if stage == "draw"]
    assert len(draws) == MAX_DRAWS - 1 and "tucker_tnn" in draws[0]
    assert all(names == ["pchip"] for names in draws[1:])
    assert np.isfinite(solver.scores_["tucker_tnn"])


def test_consensus_weighs_down_the_candidate_that_strays_on_its_gap():
    """On a gap where one of four weighted candidates strays from the others, its weight falls
    below theirs; a gap where they agree keeps its weights' ratios; a gap with fewer than three
    weighted candidates is left as it is; the weights still sum to one per sample."""
    T, J, C = 12, 3, 4
    fills = torch.zeros(C, T, J, 3, dtype=torch.float64)
    fills[:, 2:6, 0, 0] = torch.tensor([0.0, 0.1, -0.1, 5.0])[:, None]    # candidate 3 strays
    fills[:, 2:6, 1, 0] = torch.tensor([0.0, 0.1, -0.1, 0.05])[:, None]   # all agree
    missing = torch.zeros(T, J, dtype=torch.bool)
    missing[2:6] = True
    w = torch.tensor([0.4, 0.3, 0.2, 0.1], dtype=torch.float64)[:, None, None].expand(C, T, J).clone()
    w[2:, :, 2] = 0.0
    w[:, :, 2] /= w[:, :, 2].sum(dim=0)
    out = consensus(w, fills, missing)
    torch.testing.assert_close(out.sum(dim=0), torch.ones(T, J, dtype=torch.float64))
    ratio = (out[3, 2:6, 0] / out[0, 2:6, 0]) / (w[3, 2:6, 0] / w[0, 2:6, 0])
    assert bool((ratio < 0.3).all())                                      # the stray one
    assert bool((out[:3, 2:6, 0].sum(dim=0) > 0.95).all())                  # the rest: theirs
    assert bool((out[0, 2:6, 1] / out[1, 2:6, 1] > 1.0).all())            # agreeing: order kept
    torch.testing.assert_close(out[:, :, 2], w[:, :, 2])                  # two weighted: as given
    torch.testing.assert_close(out[:, :2], w[:, :2])                      # observed: as given


def test_a_choice_that_is_not_a_carry_is_an_error():
    with pytest.raises(ValueError, match="choice expected an earlier fit's carry"):
        get_solver("auto", choice={"weights": [[1.0]]})


def test_unknown_candidate_is_an_error():
    with pytest.raises(ValueError, match="candidates expected"):
        get_solver("auto", candidates=["pchip", "not_a_method"])


def test_auto_never_much_worse_than_its_best_candidate(recording):
    """CMU 02_01, 20 of 41 markers hidden over one shared 50-frame window (CP paper protocol)."""
    P = _real(recording, "cmu_02_01.c3d")
    mask = gaps.shared_window(*P.shape[:2], n_markers=20, gap_length=50, seed=2)
    X = np.where(mask[..., None], np.nan, P)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        single = {m: rmse(torchfill.fill(X, method=m), P, mask) for m in CANDIDATES}
        out = torchfill.fill(X, method="auto", candidates=list(CANDIDATES))
    np.testing.assert_array_equal(out[~mask], P[~mask])
    assert rmse(out, P, mask) <= 1.5 * min(single.values()), (rmse(out, P, mask), single)


def test_error_estimate_is_calibrated_on_a_held_out_fill(recording):
    """HDM05, Tucker-paper multi-gap mask: the real 3-D error stays within 2 sqrt(3) std for at
    least 80 % of the filled samples, and the per-gap std ranks the per-gap errors."""
    P = _real(recording, "HDM_bd_01-02_01_120.c3d", 600)
    mask = gaps.multi_gap(*P.shape[:2], n_markers=12, gap_length=60, max_gaps=3, seed=0)
    X = np.where(mask[..., None], np.nan, P)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, std = torchfill.fill(X, method="auto", return_std=True,
                                  candidates=["pchip", "svt", "tucker_tnn"])
    err = np.linalg.norm(out - P, axis=2)
    assert np.mean(err[mask] <= 2 * np.sqrt(3) * std[mask]) >= 0.8
    runs = gap_runs(mask)
    real = [np.sqrt(np.mean(err[a:b, j] ** 2)) for j, a, b in runs]
    est = [np.mean(std[a:b, j]) for j, a, b in runs]
    assert spearmanr(real, est).statistic >= 0.5


def test_auto_on_2d_keypoints_in_windows():
    """(T, J, 2) keypoints filled in two windows: the 3-D-only candidates (rigid, pma) drop out
    with their reason, the fill and its std cover every gap, observed samples stay."""
    X = _walk(T=400, J=6)[..., :2]
    X[60:90, 1] = np.nan
    X[300:320, 3] = np.nan
    missing = np.isnan(X).any(axis=2)
    out, std = torchfill.fill(X, method="auto", return_std=True, window=200,
                              candidates=["pchip", "svt", "rigid"])
    assert out.shape == X.shape and np.isfinite(out).all()
    np.testing.assert_array_equal(out[~missing], X[~missing])
    assert np.isfinite(std[missing]).all() and np.isnan(std[~missing]).all()
    solver = get_solver("auto", candidates=["pchip", "svt", "rigid"]).fit(torch.from_numpy(X))
    assert "rigid" in solver.dropped_ and "3-D" in solver.dropped_["rigid"]
    assert set(solver.scores_) == {"pchip", "svt"}


def test_trial_end_gaps_of_a_quarter_of_the_trial_are_held_out(recording):
    """Markers missing the last quarter of a trial keep a hold-out (their trial-end gap mirrored
    onto the start): the shifted copy on top would take half their samples, and the hold-out
    was empty, every candidate averaged blindly (24.6 mm here against pma's 8.8)."""
    seq = torchfill.read(recording("cmu_85_02.c3d"))
    seen = np.isfinite(seq.points[:400]).all(axis=(0, 2))
    truth = seq.select(np.flatnonzero(seen)).points[:400]
    G = truth.copy()
    hidden = np.random.default_rng(0).choice(truth.shape[1], 5, replace=False)
    G[-100:, hidden] = np.nan
    solver = get_solver("auto")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver.fit(torch.from_numpy(G))
        out = torchfill.fill(seq.select(np.flatnonzero(seen)).with_points(G), extrapolate=None)
    assert solver.scores_                                        # something was held out
    miss = np.isnan(G).any(axis=2)
    pma = torchfill.fill(G, "pma", constraints=False)
    assert rmse_missing(out.points, truth, miss) <= 1.25 * rmse_missing(pma, truth, miss)
    assert rmse_missing(out.points, truth, miss) <= 12.0                 # mm


def test_a_partial_candidate_without_held_out_gaps_of_a_kind_leans_on_its_parent():
    """Candidate 1 fills only the segment kinds (2: inside, 3: trial end) and won the held-out
    gaps inside; with no held-out trial-end gap of a segment it keeps a say there from its
    overall error instead of losing every trial-end segment sample to the others."""
    kinds = torch.tensor([0, 0, 1, 1, 2, 2])             # 0/1: inside/end, 2: inside + segment
    gap_ids = torch.tensor([0, 1, 2, 3, 4, 5])
    nan = float("nan")
    err2 = torch.tensor([[1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
                         [nan, nan, nan, nan, 0.01, 0.01]], dtype=torch.float64)
    allowed = torch.tensor([[True, False], [True, False], [True, True], [True, True]])
    W = kind_weights(err2, kinds, gap_ids, 4, combine="average", keep_ratio=1.5,
                     allowed=allowed)
    assert torch.allclose(W.sum(dim=1), torch.ones(4, dtype=torch.float64))
    assert (W[:2, 1] == 0).all()                         # not allowed outside its kinds
    assert W[2, 1] == 1.0 and W[3, 1] == 1.0             # it won the segment samples it was seen on


def test_a_partial_candidate_does_not_win_its_kinds_on_the_others_parents():
    """Candidate 1 fills only the segment kind (2), as well as candidate 0 does there; candidate 0
    also fills the hard samples elsewhere. With the segment kinds' parents taken among the
    segment samples the two share the kind; over all gaps candidate 0's parent held its hard
    samples and candidate 1 won on the shrinkage alone."""
    kinds = torch.tensor([0] * 8 + [2, 2])                 # 0: inside, 2: inside + segment
    gap_ids = torch.arange(10)
    nan = float("nan")
    err2 = torch.tensor([[1.0] * 8 + [0.01, 0.01],
                         [nan] * 8 + [0.01, 0.01]], dtype=torch.float64)
    allowed = torch.tensor([[True, False], [True, False], [True, True], [True, True]])
    over_all = kind_weights(err2, kinds, gap_ids, 4, combine="average", keep_ratio=1.5,
                            allowed=allowed)
    within = kind_weights(err2, kinds, gap_ids, 4, combine="average", keep_ratio=1.5,
                          allowed=allowed, partial_from=2)
    assert over_all[2, 1] == 1.0
    assert torch.allclose(within[2], torch.tensor([0.5, 0.5], dtype=torch.float64))
    assert torch.equal(within[:2], over_all[:2])          # the other kinds as before


def test_the_error_model_holds_each_feature_within_the_hold_outs_range():
    """A real gap standing still where every held-out gap moved (a trial end at rest): the
    log-linear model, fitted with an error that falls as the motion grows, is not extrapolated
    to the lower motion -- the gap gets the estimate of the slowest held-out motion, not one
    that explodes; inside the range the fit is read as it is."""
    from torchfill.solvers.selection.error_model import fit_std

    g = torch.Generator().manual_seed(0)
    T, J = 400, 2
    seen = torch.ones(T, J, dtype=torch.bool)
    seen[:3, 0] = seen[200:203, 0] = False          # real gaps: at rest, and in motion
    V = torch.zeros_like(seen)
    V[20:380, 1] = True
    motion = torch.ones(T, J, dtype=torch.float64)
    motion[:, 1] = 1.0 + torch.rand(T, generator=g, dtype=torch.float64)   # held out: 1-2
    motion[:3, 0] = 0.01
    motion[200:203, 0] = 1.5
    one = torch.ones(T, J, dtype=torch.float64)
    noise = torch.exp(0.1 * torch.randn(T, J, generator=g, dtype=torch.float64))
    e2 = motion ** -2.0 * noise                     # the error falls with the motion
    features = (one, one, torch.zeros_like(seen), one * 0.5, one * 1e-4, one * 1e-4, one * 1e-4,
                motion, torch.zeros_like(seen), one * 1e-4)
    model, std = fit_std(V, seen, features, e2, None, torch.ones((), dtype=torch.float64))
    slowest = float(motion[V].min())
    at_rest, moving = float(std[0, 0]), float(std[200, 0])
    assert at_rest == pytest.approx(slowest ** -1.0, rel=0.1)       # not 0.01 ** -1 = 100
    assert moving == pytest.approx(1.5 ** -1.0, rel=0.1)
    _, again = fit_std(torch.zeros_like(V), seen, features, e2, model,
                       torch.ones((), dtype=torch.float64))   # an earlier window's model
    assert torch.equal(torch.nan_to_num(again), torch.nan_to_num(std))


def test_the_mixture_spread_counts_only_the_candidates_the_fill_weighs():
    """``mix2``: the candidates' spread around the combined fill by the weights that make it;
    a stray candidate with no weight there adds nothing, one with weight adds its share."""
    from torchfill.solvers.selection.error_model import mix2

    fills = torch.zeros(3, 4, 2, 3, dtype=torch.float64)
    fills[1] += 2.0
    fills[2] += 100.0                                   # stray
    w = torch.zeros(3, 4, 2, dtype=torch.float64)
    w[0], w[1] = 0.5, 0.5
    mean = (w[..., None] * fills).sum(dim=0)
    assert torch.allclose(mix2(fills, mean, w), torch.ones(4, 2, dtype=torch.float64))
    w[2, 0, 0], w[0, 0, 0] = 0.5, 0.0
    mean = (w[..., None] * fills).sum(dim=0)
    assert float(mix2(fills, mean, w)[0, 0]) == pytest.approx(49.0 ** 2)


def test_a_marker_never_seen_twice_in_a_row_has_the_median_speed_not_zero():
    """The error model's speed feature: the mean squared step where a marker is seen in two
    consecutive frames; a marker never seen so takes the other markers' median (unknown, not 0:
    a zero speed predicted errors of 0.3-0.6 mm for fills 24-627 mm off)."""
    from torchfill.solvers.selection.error_model import speed2
    step = torch.tensor([[1.0, 4.0, 9.0, 5.0], [3.0, 4.0, 9.0, 5.0]])
    both = torch.tensor([[True, True, True, False], [True, False, True, False]])
    got = speed2(step, both)
    assert got.tolist() == [2.0, 4.0, 9.0, 4.0]


def test_a_hole_in_the_segment_fill_is_joined_to_it_by_a_ramp():
    """One marker moving 5 mm a frame, a 10-frame gap: the partial candidate fills frames 1-3 and
    8-10 of it exactly (a hole at 4-7), the other everything, 10 mm off then 4 mm off: the hole gets
    the other's fill shifted by the ramp between the offsets at its sides, here the motion itself."""
    from torchfill.solvers.selection.weights import join_holes
    T = 12
    missing = torch.zeros(T, 1, dtype=torch.bool)
    missing[1:11] = True
    truth = 5.0 * torch.arange(T, dtype=torch.float64)[:, None, None].expand(T, 1, 3)
    seg = torch.where(missing[..., None], truth, float("nan"))
    seg[4:8] = float("nan")                                  # the hole
    ramp = torch.linspace(10.0, 4.0, T, dtype=torch.float64)[:, None, None]
    other = torch.where(missing[..., None], truth + ramp, truth)
    fills = torch.stack([seg, other])
    has = torch.isfinite(seg).all(-1).double()
    w = torch.stack([has, 1 - has])
    mean = (w[..., None] * torch.nan_to_num(fills)).sum(0)
    assert torch.diff(mean[:, 0, 0]).abs().max() > 12      # the step into the hole
    out = join_holes(mean, fills, w, torch.tensor([True, False]), missing)
    assert torch.allclose(out, truth)                         # the offsets' ramp was linear
    assert torch.equal(out[~missing], mean[~missing]) and torch.equal(out[1:4], mean[1:4])


def test_default_does_not_jump_where_the_segment_fill_has_a_hole(recording):
    """walking_hybrid_1_4's R_SHANK_3 gap (frames 287..375, 240 Hz): R_SHANK_4 and R_SHANK_1 are
    the file's own fill over parts of it, so the rigid candidate leaves holes; the default stepped
    36 mm at 315 and 332 (the marker's largest observed step is 19.7 mm)."""
    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_4.c3d"))
    k = list(seq.labels).index("R_SHANK_3")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq)
    steps = np.linalg.norm(np.diff(out.points[286:377, k], axis=0), axis=1)
    observed = np.linalg.norm(np.diff(seq.points[:, k], axis=0), axis=1)
    assert np.isfinite(steps).all()
    assert steps.max() < 1.5 * np.nanmax(observed)
    assert np.array_equal(out.points[~seq.mask], seq.points[~seq.mask])


def test_a_candidate_scored_on_fewer_gaps_leans_more_on_its_parent():
    """A ``+session`` twin fits the first hold-out draw only (NaN in the second draw's gaps): its
    kinds' errors are shrunk with the number of gaps it was scored on, not every gap of the kind
    (which trusted its first-draw errors as if they were two draws')."""
    from torchfill.solvers.selection.weights import kind_mse
    nan = float("nan")
    kinds = torch.tensor([0, 0, 0, 0, 1, 1, 1, 1])          # 0: inside, 1: at a trial end
    gap_ids = torch.arange(8)
    err2 = torch.tensor([[1.0] * 8,
                         [0.25, 0.25, nan, nan, 4.0, 4.0, nan, nan]], dtype=torch.float64)
    M = kind_mse(err2, kinds, gap_ids, 2, prior=10.0)
    assert torch.allclose(M[:, 0], torch.ones(2, dtype=torch.float64))   # all 8 gaps scored
    every = 2.125                                            # candidate 1 over its 4 gaps
    inside = (2 * 0.25 + 10 * every) / 12                    # 2 gaps scored inside, not 4
    assert torch.isclose(M[0, 1], torch.tensor((2 * 0.25 + 10 * inside) / 12, dtype=torch.float64))


def test_a_later_window_reuses_the_first_windows_choice(recording, monkeypatch):
    """A long recording's later windows take the first window's choice (``carry()``): only the
    candidates with weight are fitted, once, on the real gaps (no hold-out rounds), and the fill
    stays close to that of a window that chooses for itself; the error estimate covers its gaps."""
    P = _real(recording, "hdm05_bd_05-01_01_120.c3d", 1600)
    mask = np.zeros(P.shape[:2], dtype=bool)
    mask[:800] = gaps.multi_gap(800, P.shape[1], n_markers=10, gap_length=60, seed=1)
    mask[800:] = gaps.multi_gap(800, P.shape[1], n_markers=10, gap_length=60, seed=2)
    X = torch.from_numpy(np.where(mask[..., None], np.nan, P))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = get_solver("auto").fit(X[:800])
        choice = first.carry()["choice"]
        own = get_solver("auto").fit(X[800:])
        later = get_solver("auto", choice=choice)
        stages, fit_all = [], Fits.fit_all

        def spy(self, names, fit_missing, stage="fit", case=None, **kw):
            stages.append((stage, list(names)))
            return fit_all(self, names, fit_missing, stage, case, **kw)
        monkeypatch.setattr(Fits, "fit_all", spy)
        later.fit(X[800:])
    weighted = {n for k in first.weights_.values() for n in k}
    assert [s for s, _ in stages] == ["refit"] and set(stages[0][1]) == weighted
    assert later.carry()["choice"] is choice                 # passed on unchanged
    m = mask[800:]
    err = {name: rmse_missing(s.transform(X[800:]).numpy(), P[800:], m) for name, s in
           (("own", own), ("later", later))}
    assert err["later"] <= 1.25 * err["own"], err
    std = later.std_.numpy()
    assert np.isfinite(std[m]).all() and np.isnan(std[~m]).all()
    np.testing.assert_array_equal(later.transform(X[800:]).numpy()[~m], P[800:][~m])


def test_a_later_window_that_would_try_other_candidates_chooses_for_itself(monkeypatch):
    """The first window's choice holds only where a window would try the same candidates: one
    whose long interior gaps bring in ``tucker_tnn`` (absent from a first window of trial-end
    gaps) runs its own hold-out."""
    X = _walk(T=300, J=6)
    first = X.copy()
    first[:30, 1] = np.nan                                   # trial-end gaps only
    first[-25:, 3] = np.nan
    later = X.copy()
    later[100:160, 2] = np.nan                               # a long interior gap
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        choice = get_solver("auto").fit(torch.from_numpy(first)).carry()["choice"]
        assert "tucker_tnn" not in choice["tried"]
        solver = get_solver("auto", choice=choice)
        stages, fit_all = [], Fits.fit_all

        def spy(self, names, fit_missing, stage="fit", case=None, **kw):
            stages.append(stage)
            return fit_all(self, names, fit_missing, stage, case, **kw)
        monkeypatch.setattr(Fits, "fit_all", spy)
        solver.fit(torch.from_numpy(later))
    assert stages[:2] == ["fit", "draw"] and "tucker_tnn" in solver.scores_


def test_tucker_tnn_of_each_draw_runs_on_beside_the_next_draws_with_the_same_bits(
        recording, monkeypatch):
    """On a recording with few gaps (several hold-out draws, ``tucker_tnn`` in the first two),
    its fits run on in the background while the cheaper candidates make the next draws (the
    second after the first, whose ``eps`` it reuses) and are scored at the end: the fill and
    the error estimate are those of the draws made one after the other, bit for bit."""
    x = torchfill.read(recording("ktk_tennis_serve_nan.c3d"))
    behind, fit_all, attempt, spans = [], Fits.fit_all, Fits.attempt, {}

    def spy(self, names, fit_missing, stage="fit", case=None, **kw):
        outs = list(fit_all(self, names, fit_missing, stage, case, **kw))
        behind.extend((stage, n) for n, out in zip(names, outs)
                      if not isinstance(out, (torch.Tensor, Exception)))
        return outs

    def timed(self, name, fit_missing, case=None, stage="fit"):
        start = time.perf_counter()
        out = attempt(self, name, fit_missing, case, stage)
        spans.setdefault((stage, name), (start, time.perf_counter()))
        return out

    monkeypatch.setattr(Fits, "fit_all", spy)
    monkeypatch.setattr(Fits, "attempt", timed)
    torch.set_num_threads(2)                # two lanes (the tests' fixture restores the count)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, std = torchfill.fill(x, return_std=True)
        assert behind == [("fit", "tucker_tnn"), ("draw", "tucker_tnn")]
        assert spans[("draw", "tucker_tnn")][0] >= spans[("fit", "tucker_tnn")][1]
        monkeypatch.setattr(Fits, "in_lanes", lambda self, size: False)   # round by round
        again, std_again = torchfill.fill(x, return_std=True)
    assert len(behind) == 2
    assert np.array_equal(out.points, again.points, equal_nan=True)
    assert np.array_equal(np.asarray(std), np.asarray(std_again), equal_nan=True)


def test_each_candidate_through_the_post_step_in_its_lane_gives_the_batched_bits(
        recording, monkeypatch):
    """Each candidate's fill goes through the post-step in its lane as its fit ends (the shared
    part made once per mask): the fill and the error estimate are those of a post-step that
    takes each fill alone through ``constrain_candidates`` (a ``post`` without ``prepare``),
    bit for bit, and every round's fills went through it."""
    from torchfill.constraints import CandidatePost, constrain_candidates

    X = torch.as_tensor(_real(recording, "hdm05_bd_05-01_01_120.c3d", 600))
    missing = torch.zeros(X.shape[:2], dtype=torch.bool)
    missing[100:180, 3] = missing[:40, 7] = missing[300:340, 12] = True
    X = torch.where(missing[..., None], float("nan"), X)
    calls = []

    def plain(fills, mask):
        calls.append(int(mask.sum()))
        return constrain_candidates(fills, mask)
    torch.set_num_threads(2)                # two lanes (the tests' fixture restores the count)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lanes = get_solver("auto").fit(X, post=CandidatePost())
        alone = get_solver("auto").fit(X, post=plain)
    assert torch.equal(lanes.transform(X), alone.transform(X))
    assert torch.equal(torch.nan_to_num(lanes.std_, -1.0), torch.nan_to_num(alone.std_, -1.0))
    assert len(calls) >= len(alone.tried_) + 1        # the hold-out fits, then the refits
    assert int(missing.sum()) in calls


def test_prepared_post_step_is_the_post_step_of_each_fill_alone(recording):
    """What ``prepare_candidates`` shares between fills (rigid pairs and donors, step limit,
    volume) depends on the observed samples only: each fill through it is that fill through
    ``constrain`` alone, bit for bit, and the donor samples are those ``constrain`` reports."""
    from torchfill.constraints import constrain, prepare_candidates

    P = _real(recording, "hdm05_bd_05-01_01_120.c3d", 600)
    missing = np.zeros(P.shape[:2], dtype=bool)
    missing[100:180, 3] = missing[:40, 7] = missing[300:340, 12] = True
    rng = np.random.default_rng(0)
    fills = [np.where(missing[..., None], P + rng.normal(0, s, P.shape), P) for s in (1, 20)]
    one, donor = prepare_candidates(torch.as_tensor(fills[0]), torch.as_tensor(missing))
    for F in fills:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            G, report = constrain(F, missing)
        G = np.where(np.isfinite(G), G, F)
        assert np.array_equal(one(torch.as_tensor(F)).numpy(), G)
        assert np.array_equal(donor.numpy(), report.rigid_done)
    assert donor.any()


def test_a_first_fit_that_fails_in_the_background_is_dropped_as_one_that_fails_at_once(
        recording, monkeypatch):
    """``tucker_tnn`` failing while it runs on behind the first draw: the choice goes on without
    it, with the fill and estimate of a choice whose rounds run one by one."""
    from torchfill.solvers.tucker import TuckerTNN

    x = torchfill.read(recording("ktk_tennis_serve_nan.c3d"))

    def fail(self, *args, **kwargs):
        raise ValueError("non-finite fill")
    monkeypatch.setattr(TuckerTNN, "fit_transform", fail)
    torch.set_num_threads(2)                # two lanes (the tests' fixture restores the count)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver = get_solver("auto")
        out = solver.fit_transform(torch.as_tensor(x.points))
        monkeypatch.setattr(Fits, "in_lanes", lambda self, size: False)
        again = get_solver("auto").fit_transform(torch.as_tensor(x.points))
    assert solver.dropped_ == {"tucker_tnn": "non-finite fill"}
    assert "tucker_tnn" not in solver.scores_
    assert torch.equal(out, again)
    monkeypatch.undo()
    monkeypatch.setattr(TuckerTNN, "fit_transform", fail)
    from torchfill.solvers.interp import Pchip
    monkeypatch.setattr(Pchip, "fit_transform", fail)
    with pytest.raises(ValueError, match="every candidate failed"):   # the last one behind
        get_solver("auto", candidates=["pchip", "tucker_tnn"]).fit(torch.as_tensor(x.points))
