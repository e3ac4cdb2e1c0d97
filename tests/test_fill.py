"""``torchfill.fill()``: kinds in and out, max_gap, never-observed markers, mask=, bad input, and
accuracy bounds of the interpolation baselines on a real recording."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import torchfill
from torchfill import gaps, metrics, qc
from torchfill import UnfilledWarning


def walk(T: int = 80, J: int = 5, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 30.0
    return 500.0 * np.sin(t + rng.uniform(0, 6, (1, J, 3))) + rng.normal(0, 200, (1, J, 3))


def gappy_walk():
    X = walk()
    mask = np.zeros(X.shape[:2], dtype=bool)
    mask[10:20, 1] = True
    mask[40:70, 3] = True
    return X, mask, np.where(mask[..., None], np.nan, X)


# -- kinds in and out ----------------------------------------------------------------------------
def test_ndarray_in_ndarray_out_and_input_untouched():
    X, mask, G = gappy_walk()
    before = G.copy()
    out = torchfill.fill(G, method="linear")
    assert isinstance(out, np.ndarray) and out.dtype == np.float64 and out.shape == G.shape
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[~mask], X[~mask])
    np.testing.assert_array_equal(G, before)            # a new object; the input is unchanged


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_tensor_in_tensor_out(dtype):
    X, mask, G = gappy_walk()
    Gt = torch.tensor(G, dtype=dtype)
    out = torchfill.fill(Gt, method="pchip")
    assert isinstance(out, torch.Tensor) and out.dtype == dtype and out.device == Gt.device
    assert torch.equal(out[torch.from_numpy(~mask)], Gt[torch.from_numpy(~mask)])
    assert bool(torch.isfinite(out).all()) and bool(torch.isnan(Gt).any())


def test_sequence_in_sequence_out():
    X, mask, G = gappy_walk()
    seq = torchfill.MarkerSequence(points=G, labels=list("ABCDE"), rate=60.0, units="m")
    out = torchfill.fill(seq, method="spline")
    assert isinstance(out, torchfill.MarkerSequence) and out is not seq
    assert out.labels == seq.labels and out.rate == 60.0 and out.units == "m"
    np.testing.assert_array_equal(out.points[~mask], X[~mask])
    assert np.isfinite(out.points).all() and np.isnan(seq.points).any()
    np.testing.assert_array_equal(out.meta["filled"], mask)
    assert out.meta["fill_info"]["method"] == "spline"


def test_a_list_in_gives_a_list_out():
    """``fill([x, x], "pchip")`` of two tensors: two tensors back, each the single fill; recordings
    of different lengths (ragged) are each filled alone; a tuple gives a tuple."""
    X, mask, G = gappy_walk()
    x = torch.tensor(G)
    out = torchfill.fill([x, x], "pchip")
    assert isinstance(out, list) and len(out) == 2
    alone = torchfill.fill(x, "pchip")
    assert all(isinstance(o, torch.Tensor) and torch.equal(o, alone) for o in out)
    ragged = torchfill.fill((G, G[:50], torchfill.MarkerSequence(G[:, :3], list("ABC"))), "linear")
    assert isinstance(ragged, tuple) and [np.shape(r) for r in ragged[:2]] == [G.shape, (50, 5, 3)]
    assert isinstance(ragged[2], torchfill.MarkerSequence) and ragged[2].n_markers == 3
    np.testing.assert_array_equal(ragged[1], torchfill.fill(G[:50], "linear"))
    filled, std = torchfill.fill([G, G[:60]], "pchip", mask=[mask, mask[:60]], return_std=True)
    assert [f.shape for f in filled] == [G.shape, (60, 5, 3)]
    assert [s.shape for s in std] == [(80, 5), (60, 5)]
    with pytest.raises(ValueError, match=r"data\[1\]: .*shape"):
        torchfill.fill([G, G[:, :, 0]], "pchip")
    with pytest.raises(ValueError, match="2 masks"):
        torchfill.fill([G, G], "pchip", mask=mask)


def test_data_that_require_grad_are_refused():
    X, mask, G = gappy_walk()
    with pytest.raises(ValueError, match="require grad.*detach"):
        torchfill.fill(torch.tensor(G, requires_grad=True), "pchip")


def test_integer_array_is_accepted():
    X = np.arange(60).reshape(5, 4, 3)
    np.testing.assert_array_equal(torchfill.fill(X, method="linear"), X.astype(float))


# -- max_gap -------------------------------------------------------------------------------------
def test_max_gap_leaves_longer_gaps_unfilled_with_warning():
    X, mask, G = gappy_walk()                            # gaps of 10 and 30 frames
    with pytest.warns(UnfilledWarning, match="max_gap=10"):
        out = torchfill.fill(G, method="linear", max_gap=10)
    assert np.isfinite(out[10:20, 1]).all()              # 10 frames: filled
    assert np.isnan(out[40:70, 3]).all()                 # 30 frames: left alone
    np.testing.assert_array_equal(out[~mask], X[~mask])
    with warnings.catch_warnings():
        warnings.simplefilter("error")                   # all gaps short enough: no warning
        assert np.isfinite(torchfill.fill(G, method="linear", max_gap=30)).all()


def test_max_gap_negative_is_an_error():
    _, _, G = gappy_walk()
    with pytest.raises(ValueError, match="max_gap"):
        torchfill.fill(G, method="linear", max_gap=-1)


# -- markers never observed ----------------------------------------------------------------------
@pytest.mark.parametrize("method", ["linear", "pchip"])
def test_never_observed_marker_stays_nan_with_warning(method):
    X, mask, G = gappy_walk()
    G[:, 2] = np.nan
    seq = torchfill.MarkerSequence(points=G, labels=["A", "B", "GONE", "D", "E"])
    with pytest.warns(UnfilledWarning, match="never observed.*GONE"):
        out = torchfill.fill(seq, method=method)
    assert np.isnan(out.points[:, 2]).all()
    others = [0, 1, 3, 4]
    assert np.isfinite(out.points[:, others]).all()
    assert not out.meta["filled"][:, 2].any()
    with pytest.warns(UnfilledWarning, match="never observed"):
        out = torchfill.fill(torch.from_numpy(G), method=method)   # tensors too
    assert bool(torch.isnan(out[:, 2]).all())


def test_nothing_observed_at_all_does_not_crash():
    G = np.full((10, 2, 3), np.nan)
    with pytest.warns(UnfilledWarning):
        out = torchfill.fill(G, method="linear")
    assert np.isnan(out).all()


# -- mask= ---------------------------------------------------------------------------------------
def test_mask_argument_marks_extra_samples_missing():
    X = walk()
    mask = np.zeros(X.shape[:2], dtype=bool)
    mask[30:45, 0] = True
    Y = X.copy()
    Y[30:45, 0] = 1e6                                   # bad values, masked out
    out = torchfill.fill(Y, method="linear", mask=mask)
    np.testing.assert_array_equal(out[~mask], X[~mask])
    assert np.abs(out[30:45, 0]).max() < 1e4
    ref = torchfill.fill(np.where(mask[..., None], np.nan, X), method="linear")
    np.testing.assert_array_equal(out, ref)


def test_mask_of_wrong_shape_is_an_error():
    X = walk()
    with pytest.raises(ValueError, match="mask expected shape"):
        torchfill.fill(X, method="linear", mask=np.zeros((3, 3), dtype=bool))


# -- bad input -----------------------------------------------------------------------------------
BAD_INPUTS = {
    "2-D": (np.zeros((10, 6)), "shape"),
    "no coordinates": (np.zeros((10, 3, 0)), "shape"),
    "one frame": (np.zeros((1, 3, 3)), "at least 2 frames"),
    "no markers": (np.zeros((10, 0, 3)), "at least"),
    "+inf": (np.where(np.arange(30).reshape(10, 1, 3) == 4, np.inf, 1.0), "infinite"),
    "-inf": (np.where(np.arange(30).reshape(10, 1, 3) == 4, -np.inf, 1.0), "infinite"),
    "text": (np.full((10, 2, 3), "x"), "numeric"),
    "tensor 2-D": (torch.zeros(10, 6), "shape"),
    "tensor inf": (torch.full((10, 2, 3), float("inf")), "infinite"),
}


@pytest.mark.parametrize("name", list(BAD_INPUTS))
def test_bad_input_is_a_one_line_value_error(name):
    data, word = BAD_INPUTS[name]
    with pytest.raises(ValueError, match=word) as err:
        torchfill.fill(data, method="linear")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kwargs,word", [
    (dict(method="no_such_method"), "unknown method 'no_such_method'"),
    (dict(method="svt", max_iter=0), "max_iter expected int >= 1, found 0"),
    (dict(method="svt", max_iter="a"), "max_iter expected int"),
    (dict(method="linear", bogus=1), "unknown hyperparameter"),
])
def test_bad_method_or_hyperparameter(kwargs, word):
    _, _, G = gappy_walk()
    with pytest.raises(ValueError, match=word) as err:
        torchfill.fill(G, **kwargs)
    assert "\n" not in str(err.value)


def test_methods_lists_the_registry():
    names = torchfill.methods()
    assert names[:3] == ["linear", "spline", "pchip"]
    assert len(names) == len(set(names))


# -- accuracy on a real recording ----------------------------------------------------------------
#: RMSE over the gaps (mm), mean over seeds 0-4 of 10 markers x one 60-frame gap
#: (``continuous_runs``) on cmu_02_01 (343 frames x 41 markers), measured:
#: linear 62.05, spline 37.01, pchip 45.02. Bounds are 1.5x those.
CMU_BOUNDS = {"linear": 1.5 * 62.05, "spline": 1.5 * 37.01, "pchip": 1.5 * 45.02}


@pytest.mark.parametrize("method", sorted(CMU_BOUNDS))
def test_interpolation_error_on_cmu_walk(recording, method):
    seq = torchfill.read(recording("cmu_02_01.c3d"))
    P = seq.points
    assert np.isfinite(P).all()
    errors = []
    for seed in range(5):
        mask = gaps.continuous_runs(seq.n_frames, seq.n_markers, n_markers=10, gap_length=60,
                                    seed=seed)
        out = torchfill.fill(seq.with_points(np.where(mask[..., None], np.nan, P)), method=method,
                             constraints=False)     # the method alone, against its bound
        assert np.isfinite(out.points).all()
        np.testing.assert_array_equal(out.points[~mask], P[~mask])
        errors.append(metrics.rmse_missing(out.points, P, mask))
    assert np.mean(errors) < CMU_BOUNDS[method]


def test_partly_missing_sample_keeps_its_finite_coordinates():
    """A sample with only x missing counts as missing; y and z are observed and stay bit-for-bit,
    also when its gap is longer than max_gap and so left unfilled."""
    X = walk()
    G = X.copy()
    G[5, 1, 0] = np.nan
    out = torchfill.fill(G, method="linear", constraints=False)
    np.testing.assert_array_equal(out[5, 1, 1:], X[5, 1, 1:])
    assert out[5, 1, 0] == pytest.approx((X[4, 1, 0] + X[6, 1, 0]) / 2)
    with pytest.warns(UnfilledWarning):
        out = torchfill.fill(G, method="linear", max_gap=0)
    np.testing.assert_array_equal(out[5, 1, 1:], X[5, 1, 1:])
    assert np.isnan(out[5, 1, 0])


def test_tucker_fill_computes_in_float32_and_keeps_float64_observed_samples(recording):
    """``tucker_tnn`` computes in float32 (its ``fill_dtype``): the output is float64, the
    observed samples are the input's bit-for-bit, and the error on a real recording stays within
    a bound of the float64 fill's (cmu_02_01, 10 markers x 60 frames: 5.4 vs 7.5 mm here)."""
    seq = torchfill.read(recording("cmu_02_01.c3d"))
    P = seq.points
    mask = gaps.continuous_runs(seq.n_frames, seq.n_markers, n_markers=10, gap_length=60, seed=0)
    given = np.where(mask[..., None], np.nan, P)
    errors = {}
    for dtype in (None, "float64"):
        out = torchfill.fill(given, "tucker_tnn", dtype=dtype, constraints=False)
        assert out.dtype == np.float64
        np.testing.assert_array_equal(out[~mask], P[~mask])
        errors[dtype] = metrics.rmse_missing(out, P, mask)
    seq_out = torchfill.fill(seq.with_points(given), "tucker_tnn")
    assert seq_out.meta["fill_info"]["dtype"] == "float32"
    assert errors[None] < 1.5 * errors["float64"] + 1.0                         # mm


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_default_fill_on_a_cuda_tensor_stays_there_and_matches_the_cpu_fill(recording):
    """The default fill (with its error estimate) of a tensor on the GPU: output and std on that
    device, observed samples bit-for-bit, and the error within a bound of the CPU fill's on a
    real recording with the Tucker paper's gaps (GPU reductions round differently)."""
    P = torchfill.read(recording("cmu_02_01.c3d")).points
    mask = gaps.continuous_runs(len(P), P.shape[1], n_markers=10, gap_length=60, seed=0)
    given = np.where(mask[..., None], np.nan, P)
    G = torch.from_numpy(given).cuda()
    out, std = torchfill.fill(G, return_std=True)
    assert out.device == G.device and std.device == G.device and out.dtype == G.dtype
    out = out.cpu().numpy()
    np.testing.assert_array_equal(out[~mask], P[~mask])
    cpu = torchfill.fill(given)
    assert metrics.rmse_missing(out, P, mask) < 1.2 * metrics.rmse_missing(cpu, P, mask) + 0.5


def test_default_leaves_markers_without_observed_motion_unfilled(recording):
    """On a real recording with a heavy mask (a third of the markers hidden over most of the
    trial, two markers seen only in isolated frames), the default leaves NaN exactly the samples
    :func:`torchfill.qc.untested` names -- those two markers' -- with one warning that counts
    them; ``extrapolate=None`` fills every sample; observed samples stay bit-for-bit."""
    seq = torchfill.read(recording("osim_gait2392_subject01_walk1.trc"))
    T, J = seq.mask.shape
    mask = seq.mask.copy()
    mask[20:T - 20, ::3] = True                                # interior gaps, 14 markers at once
    isolated = [4, 10]
    mask[:, isolated] = True
    mask[::7, isolated] = False                               # seen every 7th frame only
    mask[T - 1, isolated] = False                             # and at both trial ends
    gapped = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
    full, std, cut, got = _filled_and_cut(
        gapped, r"(\d+) filled sample\(s\) of 2 marker\(s\) left NaN")
    rule = qc.untested(mask, std)
    left = mask & np.isnan(cut.points).any(axis=2)
    assert np.isfinite(full.points).all()                      # extrapolate=None fills all
    assert np.array_equal(left, rule)                          # exactly the rule's samples
    assert set(np.flatnonzero(rule.any(axis=0))) == set(isolated)
    count = int(rule.sum())
    assert cut.meta["fill_info"]["untested"] == count > 0
    assert any(str(w.message).startswith(f"{count} filled sample(s)") for w in got)
    for out in (cut, full):
        assert np.array_equal(out.points[~mask], seq.points[~mask])



def _filled_and_cut(gapped, match: str):
    """``gapped`` filled whole (``extrapolate=None``, with its error estimate) and by the default,
    which must warn with ``match`` about what it leaves NaN: (full, std, cut, warnings)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full, std = torchfill.fill(gapped, extrapolate=None, return_std=True)
    with pytest.warns(UnfilledWarning, match=match) as got:
        cut = torchfill.fill(gapped)
    return full, std, cut, got


def test_default_leaves_a_lone_uncertain_fill_unfilled(recording):
    """On a real run whose torso and right-arm markers are never seen but for the lateral wrist
    (the OpenSim IK benchmark's heaviest mask has the same shape), the wrist is alone on its
    segment: the default leaves NaN exactly the samples
    :func:`torchfill.qc.alone` names -- the wrist's, whose fill errs by more than the QC's check
    level there -- with one warning that counts them; ``extrapolate=None`` fills them; with
    its forearm mate seen the same gaps are filled; observed samples stay bit-for-bit."""
    from torchfill.solvers.rigid import index_segments

    seq = torchfill.read(recording("osim_hamner_subject02_running.trc"))
    seq = seq.select(np.flatnonzero(~seq.mask.all(axis=0)))         # its dead L.Bicep
    seq = seq.with_points(seq.points[:150])
    labels = list(seq.labels)
    mask = seq.mask.copy()
    hidden = ["Sternum", "R.Acromium", "L.Acromium", "R.Bicep", "R.Elbow", "R.Wrist.Med"]
    mask[:, [labels.index(m) for m in hidden]] = True              # never seen
    wrist = labels.index("R.Wrist.Lat")
    mask[30:60, wrist] = mask[90:110, wrist] = True
    gapped = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
    full, std, cut, got = _filled_and_cut(gapped, r"of 1 marker\(s\) left NaN: no other marker")
    segments = index_segments(None, labels, gapped.points, ~mask)
    rule = qc.alone(np.isfinite(full.points).all(axis=2), mask, std, segments, seq.units)
    left = mask & np.isnan(cut.points).any(axis=2) & np.isfinite(full.points).all(axis=2)
    assert np.array_equal(left, rule)                                # exactly the rule's samples
    assert set(np.flatnonzero(rule.any(axis=0))) == {wrist}
    count = int(rule.sum())
    assert cut.meta["fill_info"]["alone"] == count > 0.9 * 50         # nearly all 50 gap samples
    assert any(str(w.message).startswith(f"{count} filled sample(s)") for w in got)
    error = np.linalg.norm(full.points - seq.points, axis=2)[rule]
    assert np.sqrt(np.mean(error ** 2)) > qc.EST_CHECK_MM               # a poor fill it leaves
    assert np.isfinite(full.points[mask[:, wrist], wrist]).all()       # extrapolate=None: filled
    mate = mask.copy()
    mate[:, labels.index("R.Wrist.Med")] = seq.mask[:, labels.index("R.Wrist.Med")]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seen = torchfill.fill(seq.with_points(np.where(mate[..., None], np.nan, seq.points)))
    assert np.isfinite(seen.points[mask[:, wrist], wrist]).all()       # a mate seen: filled
    for out, given in ((cut, mask), (full, mask), (seen, mate)):
        assert np.array_equal(out.points[~given], seq.points[~given])

def test_dtype_must_be_a_floating_dtype():
    for bad in ("int32", "float16", torch.bfloat16, "double precision"):
        with pytest.raises(ValueError, match="dtype expected"):
            torchfill.fill(walk(), "linear", dtype=bad)


def test_reject_reads_the_estimate_the_fill_returns(recording):
    """``reject=`` judges each gap by the error estimate ``fill()`` returns (the one raised on a
    short gap that departs from the interpolation, and bounded by what the fill can be off), so
    no interior gap it keeps has an RMS estimate above the limit (tennis: a 4-frame shoulder gap
    the estimate raises above 30 mm)."""
    seq = torchfill.read(recording("ktk_tennis_serve_nan.c3d"))
    limit = 30.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, std = torchfill.fill(seq, return_std=True)
        cut = torchfill.fill(seq, reject=limit)
    T = seq.n_frames
    interior = [(j, a, b) for j, a, b in metrics.gap_runs(seq.mask) if a > 0 and b < T]
    std_mm = np.nan_to_num(std) / seq.per_mm()               # the file is in metres
    over = [(j, a, b) for j, a, b in interior
            if np.sqrt(3.0 * np.mean(std_mm[a:b, j] ** 2)) > 1.05 * limit]
    assert over                                          # the case this test is about
    for j, a, b in over:
        assert np.isnan(cut.points[a:b, j]).all(), (seq.labels[j], a, b)


def test_reject_leaves_samples_with_a_large_estimated_error_unfilled(recording):
    """``reject=`` (mm) leaves NaN the filled samples whose error estimate is above it, with one
    warning; the default keeps every fill (its estimate goes to the QC instead)."""
    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_1.c3d"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kept, std = torchfill.fill(seq, return_std=True)
    with pytest.warns(torchfill.filling.UnfilledWarning, match="estimated error is above 30 mm"):
        cut = torchfill.fill(seq, reject=30.0)
    big = np.sqrt(3.0) * np.nan_to_num(std, nan=0.0) > 31.5      # 5 %: two fills' estimates
    T = seq.n_frames                                              # differ in the last digits
    ends = np.zeros_like(big)                   # samples in gaps that touch one trial end
    for j, a, b in metrics.gap_runs(seq.mask):
        ends[a:b, j] = (a == 0) != (b == T)
    earlier = seq.meta.get("filled")            # the file's own earlier fills are put back
    ends &= ~(earlier if earlier is not None else np.zeros_like(ends))
    dropped = np.isfinite(kept.points).all(axis=2) & np.isnan(cut.points).any(axis=2)
    # (the count also holds samples the file marks as filled earlier, which are put back)
    assert cut.meta["fill_info"]["rejected"] >= int(dropped.sum()) > 0
    assert np.isnan(cut.points[big & ends]).all()      # at a trial end: every sample above it
    assert np.isfinite(kept.points[big]).all()         # kept by default
    observed = ~seq.mask
    assert np.array_equal(cut.points[observed], seq.points[observed])
