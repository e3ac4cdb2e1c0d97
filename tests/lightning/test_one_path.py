"""One path for one case: the experiment runner scores what ``torchfill.fill`` returns.

Each case of a shipped config is run by the runner (its Lightning Trainer driving ``step()``) and,
independently, by ``torchfill.fill`` with the papers' protocol spelled out in fill()'s own
arguments; the fills must agree bit for bit, and the row must score that fill.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill import metrics
from torchfill.lightning import runner
from torchfill.lightning.config import load_config
from torchfill.sequence import MarkerSequence
from torchfill.solvers import get_solver

REPO = Path(__file__).resolve().parents[2]
#: fill()'s arguments for the papers' protocol: the method's own fill, the whole recording at
#: once, no extrapolation limit, the configs' float64
PAPER = {"window": None, "constraints": False, "extrapolate": None, "dtype": "float64"}
CASES = [   # config, method label, what fill() gets besides PAPER
    ("smoke.yaml", "svt", {}),
    ("pca_tables.yaml", "pca_train", {"training": "config"}),     # other recordings, by label
    ("pca_tables.yaml", "pca_train_self", {"training": "rest"}),   # the rest of the recording
    pytest.param("constraints_cp.yaml", "cp+c", {"constraints": True},   # fill()'s post-step
                 marks=pytest.mark.slow),                                # two cp fits: ~15 s
]


@pytest.mark.parametrize("config, label, extra", CASES,
                         ids=["smoke-svt", "pca_tables-pca_train", "pca_tables-pca_train_self",
                              "constraints_cp-cp+c"])
def test_runner_and_fill_agree_bit_for_bit(config, label, extra, data_dir, recording, tmp_path,
                                           monkeypatch):
    monkeypatch.setenv("TORCHFILL_DATA", str(data_dir))
    path = REPO / "experiments" / config
    cfg = load_config(path)
    for name in cfg.recordings[:1] + cfg.training:
        recording(name)
    case = next(c for c in cfg.cases() if c.method.label == label)
    row = runner.run_case(str(path), case, str(tmp_path), showcase=True)
    assert row["status"] == "ok", row["status"]
    with np.load(tmp_path / "showcase" / f"{label}.npz") as saved:
        by_runner = saved["filled"]

    rec, mask, rest = runner.case_data(cfg, case.recording, case.point, case.seed)
    X = np.where(mask[..., None], np.nan, rec.truth)
    kwargs = {**PAPER, **extra}
    if extra.get("training") == "config":
        kwargs["training"] = [torchfill.read(cfg.recording_path(n)) for n in cfg.training]
        X = MarkerSequence(X, list(rec.labels), rate=rec.rate, units=rec.units)
    elif extra.get("training") == "rest":
        kwargs["training"] = rest
    params = {k: v for k, v in case.method.params.items() if k not in ("training", "constraints")}
    own = get_solver(case.method.solver).get_params()
    if "window" in own:          # fill()'s window=None is not the method's (pca's is its own)
        params.setdefault("window", own["window"])
    by_fill = torchfill.fill(X, case.method.solver, params=params or None, **kwargs)
    by_fill = by_fill.points if isinstance(by_fill, MarkerSequence) else by_fill

    assert np.isfinite(by_fill).all() and by_fill.shape == rec.truth.shape
    assert np.array_equal(by_runner, by_fill)
    score = metrics.score(by_fill, rec.truth, mask)
    assert float(row["rmse"]) == score["rmse"] and float(row["gap_error"]) == score["gap_error"]
    assert 0 < score["rmse_missing"] < 300.0     # mm: centimetres at worst (svt at 20 iterations)


def test_a_config_can_score_what_fill_returns_by_default(data_dir, recording, tmp_path,
                                                          monkeypatch):
    """``fill:`` with fill()'s defaults: the row scores ``torchfill.fill(seq, method)`` as is
    (constraints, extrapolation limit, windows, the method's own dtype: float32 for tucker)."""
    monkeypatch.setenv("TORCHFILL_DATA", str(data_dir))
    recording("hdm05_dg_06-03_03_120.c3d")
    path = tmp_path / "fill.yaml"
    path.write_text(f"base: {REPO / 'experiments' / 'smoke.yaml'}\n"
                    "fill: {sequence: true, constraints: true, extrapolate: 0.25, window: 6000, "
                    "dtype: null}\nmethods: {linear: ~, svt: ~, tucker: {max_iter: 30}}\n")
    cfg = load_config(path)
    (case,) = cfg.cases()
    row = runner.run_case(str(path), case, str(tmp_path), showcase=True)
    assert row["status"] == "ok", row["status"]
    with np.load(tmp_path / "showcase" / "tucker.npz") as saved:
        by_runner = saved["filled"]
    rec, mask, _ = runner.case_data(cfg, case.recording, case.point, case.seed)
    seq = MarkerSequence(np.where(mask[..., None], np.nan, rec.truth), list(rec.labels),
                         rate=rec.rate, units=rec.units)
    by_fill = torchfill.fill(seq, "tucker", params={"max_iter": 30})
    assert by_fill.meta["fill_info"]["dtype"] == "float32"
    assert np.array_equal(by_runner, by_fill.points, equal_nan=True)
    score = metrics.score(by_fill.points, rec.truth, mask)    # NaN where the limit left gaps
    assert np.array_equal([float(row[k]) for k in score], list(score.values()), equal_nan=True)
