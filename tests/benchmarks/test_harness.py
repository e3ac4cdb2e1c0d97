"""The benchmark harness: the shipped masks are the ones the gapped recordings give, result rows
resume, the scores split the hidden samples as documented, and a peer never changes an observed
sample."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks import cases, scores
from benchmarks.rows import Rows, read_csv


def test_shipped_masks_are_the_derived_ones_and_hold_out_five_sources(data_dir):
    shipped = cases.load_masks(data_dir)
    derived = cases.build_real_gaps(data_dir)
    assert [c.name for c in shipped] == [c.name for c in derived]
    for a, b in zip(shipped, derived):
        assert np.array_equal(a.mask, b.mask) and a.truth.labels == b.truth.labels
        assert np.array_equal(a.truth.points, b.truth.points)
        assert np.isfinite(a.truth.points).all() and a.mask.any()
    held = {c.source.rsplit(".", 1)[0] for c in shipped if c.split == "held-out"}
    assert held == set(cases.HELD_OUT)
    tuning = {c.source for c in shipped if c.split == "tuning"}
    assert not tuning & {c.source for c in shipped if c.split == "held-out"}
    assert {c.name for c in cases.select(shipped, quick=True)} == set(cases.QUICK)


def test_rows_resume_and_replace(tmp_path):
    path = tmp_path / "rows.csv"
    rows = Rows(path, ("case", "method"))
    rows.add({"case": "a", "method": "pma", "rmse": 1.5})
    rows.add({"case": "a", "method": "default", "rmse": 2.0})
    again = Rows(path, ("case", "method"))
    assert again.done(case="a", method="pma") and not again.done(case="b", method="pma")
    again.add({"case": "a", "method": "pma", "rmse": 1.25})
    assert [(r["method"], r["rmse"]) for r in read_csv(path)] == [("default", "2"),
                                                                ("pma", "1.25")]


def test_marker_scores_split_trial_end_and_interior():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(20, 3, 3))
    mask = np.zeros((20, 3), bool)
    mask[:4, 0] = True          # touches the first frame
    mask[8:12, 1] = True        # interior
    F = truth.copy()
    F[:4, 0] += 3.0
    F[8:12, 1] += 1.0
    F[10:12, 1] = np.nan        # left missing by the method
    rest = truth + 1.0
    got = scores.marker_scores(F, truth, mask, rest)
    assert got["left"] == pytest.approx(2 / 8)
    assert got["rmse_end"] == pytest.approx(3.0) and got["rmse_interior"] == pytest.approx(1.0)
    assert got["rmse_own"] == pytest.approx(np.sqrt((4 * 9 + 2) / 6))
    assert got["rmse"] == pytest.approx(np.sqrt((4 * 9 + 4) / 8))


def test_verdict_accuracy_pools_counts():
    acc, big, small = scores.verdict_accuracy([
        {"n_big": 2, "big_flagged": 1, "n_small": 8, "small_ok": 8},
        {"n_big": 0, "big_flagged": 0, "n_small": 10, "small_ok": 9}])
    assert acc == pytest.approx(18 / 20) and big == 0.5 and small == pytest.approx(17 / 18)


@pytest.mark.parametrize("peer", ["gapfill", "ktk_interp", "iterative_imputer"])
def test_a_peer_keeps_observed_samples_and_fills_some_hidden_ones(peer, data_dir):
    from benchmarks import peers

    if not peers.available(peer):
        pytest.skip(f"{peer} is not installed")
    case = next(c for c in cases.load_masks(data_dir) if c.name in cases.QUICK)
    X = case.gapped()
    F = peers.fill(peer, X)
    seen = ~case.mask
    assert np.array_equal(F[seen], X.points[seen])
    assert np.isfinite(F[case.mask]).all(axis=1).any()


def test_help_lists_every_suite(capsys):
    from benchmarks.__main__ import main
    from benchmarks.suites import SUITES

    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    for name in ("real-gaps", "masks", "ik", "segments", "qc", "session", "speed", "peers",
                 "papers", "docs"):
        assert name in SUITES and f"    {name}" in text


def test_real_gaps_list_prints_the_held_out_cases(data_dir, capsys):
    from benchmarks.__main__ import main

    assert main(["real-gaps", "--split", "held-out", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 10 and all(line.endswith("[held-out]") for line in lines)
