"""The experiment runner: configs, the smoke experiment, resume after an interruption, reports."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from torchfill.lightning import config as config_mod
from torchfill.lightning import report, runner
from torchfill.lightning.config import load_config

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "experiments" / "smoke.yaml"


def rows(out: Path) -> list[dict]:
    with open(out / "cases.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def write_config(tmp_path: Path, text: str, name: str = "exp.yaml") -> Path:
    path = tmp_path / name
    path.write_text(f"base: {SMOKE}\n" + text)
    return path


@pytest.fixture
def smoke_data(data_dir, recording, monkeypatch):
    recording("hdm05_dg_06-03_03_120.c3d")
    monkeypatch.setenv("TORCHFILL_DATA", str(data_dir))
    return data_dir


def test_smoke_experiment_end_to_end(smoke_data, tmp_path):
    out = runner.run_experiment(SMOKE, output=tmp_path / "smoke")
    got = rows(out)
    assert [r["method"] for r in got] == ["linear", "svt"]
    assert all(r["status"] == "ok" for r in got)
    assert got[0]["n_iter"] == "1" and 1 < int(got[1]["n_iter"]) <= 20
    for r in got:
        # 1-3 gaps of 40 frames (1/3 s at 120 Hz) on 5 of 41 markers: interpolation errs by
        # centimetres inside the gaps, never by metres, and never exactly 0
        assert 1.0 < float(r["rmse_missing"]) < 300.0
        assert float(r["rmse"]) < float(r["rmse_missing"])       # observed entries count as 0
        assert int(r["J"]) == 41 and int(r["T"]) == 202
    table = (out / "table.md").read_text()
    assert "torchfill experiment experiments/smoke.yaml" in table
    best = min(got, key=lambda r: float(r["rmse"]))
    assert f"**{float(best['rmse']):.2f} ± 0.00**" in table
    assert (out / "trajectories.png").stat().st_size > 1000
    assert (out / "convergence.png").stat().st_size > 1000        # svt iterates
    logs = list((out / "runs" / "logs").glob("*svt*/metrics.csv"))
    assert len(logs) == 1 and len(logs[0].read_text().splitlines()) == int(got[1]["n_iter"]) + 1
    assert "time_s" in logs[0].read_text().splitlines()[0].split(",")   # solver seconds per step


def test_interrupt_then_resume_runs_only_unfinished_cases(smoke_data, tmp_path, monkeypatch):
    out = tmp_path / "smoke"
    real = runner.run_case
    calls = []

    def interrupted(config_path, case, runs_dir, **kw):
        calls.append(case.method.label)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(config_path, case, runs_dir, **kw)

    monkeypatch.setattr(runner, "run_case", interrupted)
    with pytest.raises(KeyboardInterrupt):
        runner.run_experiment(SMOKE, output=out)
    first = rows(out)
    assert [r["method"] for r in first] == ["linear"]
    assert calls == ["linear", "svt"]
    with open(out / "cases.csv", "a") as handle:        # a torn line, as if killed mid-write
        handle.write("hdm05_dg_06-03_03_120.c3d,5,4")

    calls.clear()
    monkeypatch.setattr(runner, "run_case", lambda *a, **kw: calls.append(a[1].method.label) or real(*a, **kw))
    runner.run_experiment(SMOKE, output=out, resume=True)
    assert calls == ["svt"]
    final = rows(out)
    assert [r["method"] for r in final] == ["linear", "svt"]
    assert final[0] == first[0]                          # the finished case was kept, not redone

    calls.clear()
    runner.run_experiment(SMOKE, output=out, resume=True)
    assert calls == [] and len(rows(out)) == 2

    (out / "table.md").unlink()
    with open(out / "cases.csv") as handle:
        kept = handle.readlines()[:2]                      # header + linear: svt "not run"
    (out / "cases.csv").write_text("".join(kept))
    runner.run_experiment(SMOKE, output=out, report_only=True)
    assert calls == [] and [r["method"] for r in rows(out)] == ["linear"]
    assert "| linear | 1 |" in (out / "table.md").read_text()


def test_limit_and_unregistered_methods(smoke_data, tmp_path, capsys):
    path = write_config(tmp_path, "methods: {linear: {}, not_a_method_yet: {max_iter: 3}}\n")
    out = runner.run_experiment(path, output=tmp_path / "o", limit=1)
    assert "method 'not_a_method_yet' is not registered; skipped" in capsys.readouterr().out
    assert [r["method"] for r in rows(out)] == ["linear"]
    assert "not_a_method_yet" in (out / "table.md").read_text()


def test_same_solver_twice_under_two_labels(smoke_data, tmp_path):
    path = write_config(tmp_path, "methods: {linear: ~, svt: ~, a: {method: linear}, b: {method: spline}}\n")
    got = rows(runner.run_experiment(path, output=tmp_path / "o"))
    assert [(r["method"], r["solver"]) for r in got] == [("a", "linear"), ("b", "spline")]


@pytest.mark.parametrize("text, match", [
    ("protocol: nope\n", "unknown protocol 'nope'"),
    ("recordings: [missing_file.c3d]\n", "recording missing_file.c3d not found"),
    ("colour: red\n", "unknown key"),
    ("methods: {svt: {max_iter: -1}}\n", "methods.svt"),
    ("grid: {gap_length: [100000]}\n", "gap_length"),
    ("metrics: [rmse, accuracy]\n", "unknown metric"),
    ("frames: [0, 100]\nsegments: {length: 50, count: 2}\n", "frames and segments exclude"),
    ("segments: {length: 50}\n", "segments expected"),
    ("segments: {length: 500, count: 2}\n", "distinct segments of 500 frames"),
    ("methods: {a: {method: linear, training: self}}\n", "training: self needs `segments:`"),
    ("methods: {a: {method: pca_train, training: [absent.c3d]}}\n", "training recording absent.c3d"),
    ("table: {metric: gap_error}\n", "table metric 'gap_error' is not in metrics"),
    ("table: {rows: [recording, colour]}\n", "table key 'colour'"),
    ("references: {paper: [{recording: a.c3d, rmse: 1.0}]}\n", "references.paper"),
    ("base: absent.yaml\n", "absent.yaml: no such config file"),
])
def test_config_errors_are_one_line_value_errors(smoke_data, tmp_path, text, match):
    path = write_config(tmp_path, text, name="broken.yaml")
    with pytest.raises(ValueError, match=match) as err:
        runner.run_experiment(path, output=tmp_path / "o")
    assert str(err.value).startswith("broken.yaml: ") and "\n" not in str(err.value)


def test_main_reports_errors_with_status_2(tmp_path, capsys):
    assert runner.main([str(tmp_path / "absent.yaml")]) == 2
    assert "absent.yaml: no such config file" in capsys.readouterr().err


def test_base_config_deep_merge(tmp_path, monkeypatch):
    monkeypatch.delenv("TORCHFILL_DATA", raising=False)
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "a.c3d").write_bytes(b"")      # load_config checks files, reads none
    (tmp_path / "base.yaml").write_text(
        "recordings: [a.c3d]\nprotocol: multi_gap\ngrid: {n_markers: [5], gap_length: [40]}\n"
        "methods: {linear: {}}\nseeds: [0, 1]\ndata_dir: data\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "child.yaml").write_text("base: ../base.yaml\ngrid: {gap_length: [10, 20]}\n")
    monkeypatch.chdir(tmp_path / "sub")
    cfg = load_config("child.yaml")
    # folders come from the config files' locations: data_dir from the base file that sets it,
    # results beside the config that was run; never from the package's location
    assert cfg.data_dir == tmp_path / "data" and cfg.results_dir == tmp_path / "sub" / "results"
    assert cfg.name == "child" and cfg.grid == {"n_markers": [5], "gap_length": [10, 20]}
    assert len(cfg.cases()) == 1 * 2 * 2 * 1
    assert config_mod.deep_merge({"a": {"b": 1, "c": 2}}, {"a": {"c": 3}}) == {"a": {"b": 1, "c": 3}}
    assert config_mod.deep_merge({"a": {"b": 1, "c": 2}}, {"a": {"c": None}}) == {"a": {"b": 1}}


def test_table_is_mean_std_over_seeds_with_best_in_bold():
    data = [{"recording": "r", "gap_length": "50", "seed": str(s), "method": m, "rmse": str(v),
             "status": "ok"} for m, vals in {"a": [1.0, 3.0], "b": [1.5, 1.5]}.items()
            for s, v in enumerate(vals)]
    data.append({"recording": "r", "gap_length": "50", "seed": "2", "method": "a", "rmse": "99",
                 "status": "error: boom"})
    text = report.table_markdown(data, ["recording", "gap_length"], "method", "rmse", ["a", "b"])
    assert f"| r | 50 | 2.00 ± {math.sqrt(2):.2f} | **1.50 ± 0.00** |" in text


def test_training_recordings_aligned_by_label_only_for_solvers_that_take_them(smoke_data, tmp_path,
                                                                             monkeypatch, recording):
    import torchfill.filling as filling
    import torchfill.solvers as solvers
    from torchfill.lightning.data import load_recording, read_sequence

    recording("cmu_02_01.c3d")
    train = smoke_data / "hdm05_dg_06-03_03_120.c3d"
    if "pca_train" not in solvers.available():
        pytest.skip("pca_train not registered")
    calls = []
    real = filling.fill_case

    def spy(data, options, **kw):
        calls.append((options.method, options.training))
        return real(data, options, **kw)

    monkeypatch.setattr(filling, "fill_case", spy)
    path = write_config(tmp_path, "recordings: [cmu_02_01.c3d]\ntraining: [hdm05_dg_06-03_03_120.c3d]\n"
                        "methods: {svt: ~, pca_train: {}, self: {method: pca_train, training: ~}}\n")
    got = rows(runner.run_experiment(path, output=tmp_path / "o"))
    assert [r["status"] for r in got] == ["ok"] * 3
    assert [n for n, _ in calls] == ["linear", "pca_train", "pca_train"]
    assert calls[0][1] is None                               # linear takes no training data
    given = [t for n, t in calls if n == "pca_train"]
    assert given[1] is None                                  # the 'self' method: no training set
    (A,) = given[0]
    test_labels = load_recording(smoke_data / "cmu_02_01.c3d").labels
    seq = read_sequence(train)
    assert A.shape == (seq.n_frames, len(test_labels), 3)
    src = seq.short_labels()
    for j, label in enumerate(test_labels):
        if label in src:
            np.testing.assert_array_equal(A[:, j], seq.points[:, src.index(label)])
        else:
            assert np.isnan(A[:, j]).all()


def test_plan_lists_cases_and_resume_keeps_only_finished_rows(smoke_data, tmp_path):
    from torchfill.lightning import rows as R

    path = write_config(tmp_path, "seeds: [0, 1]\nshowcase: {seed: 1}\n")
    p = runner.plan(path, output=tmp_path / "o")
    assert [(c.seed, c.method.label) for c in p.todo] == [(0, "linear"), (0, "svt"), (1, "linear"),
                                                         (1, "svt")]
    assert p.header == R.columns(["n_markers", "gap_length", "max_gaps"]) and not p.done
    assert p.runs_dir == tmp_path / "o" / "runs" and "202 frames" in p.notes[0]
    finished = {**R.key_row(p.cases[0]), "solver": "linear", "rmse": "1.0", "status": "ok"}
    failed = {**R.key_row(p.cases[1]), "solver": "svt", "status": "error: boom"}
    (tmp_path / "o").mkdir()
    R.rewrite(tmp_path / "o" / "cases.csv", p.header, [finished, failed])
    again = runner.plan(path, output=tmp_path / "o", resume=True)
    assert [c.key for c in again.todo] == [c.key for c in p.cases[1:]]   # failed case runs again
    assert list(again.done) == [p.cases[0].key]
    assert runner.plan(path, output=tmp_path / "o", limit=3).todo == p.todo[:3]


def test_report_rows_references_mean_stability_and_diagnostics():
    def row(rec, L, seed, method, rmse, n_iter="1", rank=""):
        return {"recording": rec, "gap_length": str(L), "seed": str(seed), "method": method,
                "rmse": str(rmse), "n_iter": n_iter, "rank": rank, "status": "ok"}

    data = [row("r.c3d", 50, s, "a", v) for s, v in enumerate([1.0, 1.0, 4.0])]
    data += [row("r.c3d", 50, s, "b", 2.5, "30", "5x5x3") for s in range(3)]
    data += [row("r.c3d", 100, s, "a", 3.0) for s in range(3)]
    data += [row("r.c3d", 100, s, "b", 1.0, "40", "6x6x3" if s else "5x5x3") for s in range(3)]
    refs = {"paper": [{"recording": "r", "gap_length": "50", "rmse": 0.5}],
            "unmatched": [{"recording": "x", "gap_length": "50", "rmse": 9.0}]}
    text = report.table_markdown(data, ["recording", "gap_length"], "method", "rmse", ["a", "b"],
                                 references=refs)
    lines = text.splitlines()
    assert lines[0] == "| recording | gap_length | paper | a | b |"       # unmatched column dropped
    assert lines[2] == f"| r.c3d | 50 | 0.50 | **2.00 ± {math.sqrt(3):.2f}** | 2.50 ± 0.00 |"
    assert lines[3] == "| r.c3d | 100 | – | 3.00 ± 0.00 | **1.00 ± 0.00** |"
    assert lines[4] == "| mean of 2 rows |  |  | 2.50 | **1.75** |"
    text = report.table_markdown(data[:-1], ["recording", "gap_length"], "method", "rmse", ["a", "b"])
    assert text.splitlines()[3] == "| r.c3d | 100 | 3.00 ± 0.00 | **1.00 ± 0.00** (n=2) |"
    check = report.stability_markdown(data, ["recording", "gap_length"], "rmse", ["a", "b"])
    assert "| a | 4.00 | r.c3d 50 | 3 |" in check and "| b | 1.00 |" in check
    diag = report.diagnostics_markdown(data, ["recording", "gap_length"], ["a", "b"])
    assert "| r.c3d | 50 | 1 | 30 / 5x5x3 |" in diag and "| r.c3d | 100 | 1 | 40 / 6x6x3 |" in diag


def test_segments_cut_the_recording_and_self_training_is_the_rest(smoke_data, tmp_path):
    path = write_config(tmp_path, "segments: {length: 50, count: 3}\nmethods: {svt: ~, "
                        "p: {method: pca_train, training: self}}\n")
    cfg = load_config(path)
    assert cfg.keys[0] == "segment" and len(cfg.cases()) == 3 * 1 * 2
    full = cfg.recording_path(cfg.recordings[0])
    from torchfill.lightning.data import load_recording

    truth = load_recording(full).truth
    seen = []
    for case in cfg.cases()[1::2]:
        rec, mask, rest = runner.case_data(cfg, case.recording, case.point, case.seed)
        s0 = [s for s in range(len(truth) - 49) if np.array_equal(truth[s:s + 50], rec.truth)][0]
        seen.append(s0)
        assert mask.shape == (50, truth.shape[1]) and mask.any()
        np.testing.assert_array_equal(np.concatenate(rest), np.delete(truth, range(s0, s0 + 50), 0))
        options = runner.fill_options(cfg, case, rec, rest)
        assert "training" not in options.params
        assert sum(len(a) for a in options.training) == len(truth) - 50   # never the segment
    assert seen == sorted(set(seen)) and len(seen) == 3


def test_experiment_without_the_extra_is_a_one_line_error(monkeypatch, capsys):
    import sys

    from torchfill import cli

    for name in [m for m in sys.modules if m.startswith("torchfill.lightning")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "yaml", None)           # as if PyYAML were not installed
    assert cli.main(["experiment", str(SMOKE)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("torchfill: error: ")
    assert "pip install 'torchfill[experiments]'" in err and "yaml" in err


@pytest.mark.parametrize("path", sorted((REPO / "experiments").glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_config_loads_against_the_shared_data(path, data_dir, monkeypatch):
    """Each config's recordings resolve from its own data_dir (relative to the file), as
    ``torchfill experiment experiments/X.yaml`` from a checkout beside ../shared needs."""
    monkeypatch.delenv("TORCHFILL_DATA", raising=False)
    if data_dir.resolve() != (REPO.parent / "shared" / "data").resolve():
        pytest.skip("the shared data are not at ../shared/data beside this checkout")
    cfg = load_config(path)
    assert cfg.cases() and all(cfg.recording_path(r).is_file() for r in cfg.recordings)
