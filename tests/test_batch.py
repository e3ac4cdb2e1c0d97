"""Batch fills: many files through one CLI call, locally in processes or on a local Ray; a bad
file is reported in one line and the others are still filled; outputs equal one-by-one fills."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from torchfill.cli import main


@pytest.fixture
def folder(tmp_path, walk):
    src = tmp_path / "in"
    src.mkdir()
    for k in range(3):
        X = walk(120, 5, seed=k)
        X[30 + k:50 + k, 1] = np.nan
        X[80:90, 3] = np.nan
        np.savez(src / f"trial{k}.npz", points=X, labels=np.array([f"M{j}" for j in range(5)]),
                 rate=100.0, units="mm")
    (src / "broken.npz").write_bytes(b"not a recording")
    return src


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_batch_fills_all_and_reports_the_bad_file(folder, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["fill", str(folder), "--out-dir", str(out), "-m", "linear", "--workers", "2"])
    captured = capsys.readouterr()
    assert code == 2                                   # one file failed
    errors = [line for line in captured.err.splitlines() if line.startswith("torchfill: error:")]
    assert len(errors) == 1 and "broken.npz" in errors[0]
    assert sorted(p.name for p in out.iterdir()) == ["trial0.npz", "trial1.npz", "trial2.npz"]
    assert "3 of 4 file(s) filled, 1 failed" in captured.out
    for k in range(3):
        given = np.load(folder / f"trial{k}.npz")["points"]
        filled = np.load(out / f"trial{k}.npz")["points"]
        seen = np.isfinite(given)
        assert np.array_equal(filled[seen], given[seen]) and np.isfinite(filled).all()


def test_batch_equals_single_file_fills(folder, tmp_path):
    good = sorted(str(p) for p in folder.glob("trial*.npz"))
    assert main(["fill", *good, "--out-dir", str(tmp_path / "batch"), "-m", "pchip", "-q",
                 "--workers", "2"]) == 0
    for path in good:
        single = tmp_path / "single.npz"
        assert main(["fill", path, "-o", str(single), "-m", "pchip", "-q"]) == 0
        a, b = np.load(single), np.load(tmp_path / "batch" / path.split("/")[-1])
        assert np.array_equal(a["points"], b["points"])


def test_batch_refuses_to_overwrite_inputs(folder, capsys):
    code = main(["fill", str(folder / "trial0.npz"), "--out-dir", str(folder), "-m", "linear"])
    assert code == 2 and "overwrite the input" in capsys.readouterr().err


def test_several_inputs_need_out_dir(folder, capsys):
    code = main(["fill", str(folder / "trial0.npz"), str(folder / "trial1.npz"), "-m", "linear"])
    assert code == 2 and "--out-dir" in capsys.readouterr().err


def _cases(out):
    """(method, rmse to 12 significant digits, iterations): a Ray worker's torch thread count may
    differ from this process's, which reorders float sums in the last digits."""
    with open(out / "cases.csv", newline="") as handle:
        return sorted((r["method"], f"{float(r['rmse']):.12g}", r["n_iter"])
                      for r in csv.DictReader(handle))


@pytest.mark.slow
def test_ray_gives_the_local_results(folder, tmp_path, data_dir, monkeypatch):
    """Files as Ray tasks are byte-identical to a local batch; an experiment grid run as Ray tasks
    gives the local cases' numbers. One local Ray (2 CPUs) started here serves both: a new one
    (``address="local"``), never a cluster that ``RAY_ADDRESS`` or an earlier ``ray start`` on this
    machine points to (its workers import whichever torchfill their own paths find)."""
    ray = pytest.importorskip("ray")
    smoke = Path(__file__).resolve().parents[1] / "experiments" / "smoke.yaml"
    if not (data_dir / "hdm05_dg_06-03_03_120.c3d").is_file():
        pytest.skip("smoke recording absent")
    from torchfill.lightning import runner

    good = sorted(str(p) for p in folder.glob("trial*.npz"))
    assert main(["fill", *good, "--out-dir", str(tmp_path / "local"), "-m", "pchip", "-q"]) == 0
    local = runner.run_experiment(smoke, output=tmp_path / "exp_local")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        assert main(["fill", *good, "--out-dir", str(tmp_path / "ray"), "-m", "pchip", "-q",
                     "--ray", "auto"]) == 0
        remote = runner.run_experiment(smoke, output=tmp_path / "exp_ray", ray_address="auto")
    finally:
        ray.shutdown()
    assert _files(tmp_path / "ray") == _files(tmp_path / "local")
    assert _cases(remote) == _cases(local) and len(_cases(local)) == 2
