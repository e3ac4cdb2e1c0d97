"""The command line: every verb has --help, bad input is one line and exit 2, fill writes a file
whose observed samples are the input's, evaluate prints the metrics."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import torchfill
from torchfill.cli import main


@pytest.fixture
def gappy_npz(tmp_path, walk):
    X = walk()
    X[40:70, 1] = np.nan
    X[100:110, 3] = np.nan
    path = tmp_path / "trial.npz"
    np.savez(path, points=X, labels=np.array([f"M{j}" for j in range(X.shape[1])]), rate=100.0,
             units="mm")
    return path, X


@pytest.mark.parametrize("verb", ["fill", "evaluate", "info", "methods", "experiment"])
def test_every_verb_has_help(verb, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([verb, "--help"])
    assert exit_.value.code == 0
    assert "usage: torchfill " + verb in capsys.readouterr().out


def test_module_entry_point_runs():
    done = subprocess.run([sys.executable, "-m", "torchfill", "methods"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0
    assert "linear" in done.stdout.split()


def test_fill_writes_and_keeps_observed(gappy_npz, tmp_path, capsys):
    path, X = gappy_npz
    out = tmp_path / "filled.npz"
    assert main(["fill", str(path), "-o", str(out), "-m", "linear", "-q"]) == 0
    Y = np.load(out)["points"]
    observed = np.isfinite(X)
    assert np.array_equal(Y[observed], X[observed])
    assert np.isfinite(Y).all()


def test_fill_max_gap_leaves_long_gap(gappy_npz, tmp_path, capsys):
    path, X = gappy_npz
    out = tmp_path / "filled.npz"
    assert main(["fill", str(path), "-o", str(out), "-m", "linear", "--max-gap", "20", "-q"]) == 0
    Y = np.load(out)["points"]
    assert np.isnan(Y[40:70, 1]).all() and np.isfinite(Y[100:110, 3]).all()
    assert "left unfilled" in capsys.readouterr().err


def test_evaluate_json(gappy_npz, capsys):
    path, _ = gappy_npz
    code = main(["evaluate", str(path), "-m", "linear,pchip", "--markers", "2", "--gap-length", "20",
                 "--max-gaps", "2", "--json", "-q"])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert [row["method"] for row in report["results"]] == ["linear", "pchip"]
    assert all(row["rmse_missing"] > 0 for row in report["results"])


def test_info_lists_gaps(gappy_npz, capsys):
    path, _ = gappy_npz
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "2 gaps, longest 30 frames" in out


@pytest.mark.parametrize("args, needle", [
    (["fill", "{missing}"], "no such file"),
    (["fill", "{bad_suffix}"], "unsupported file type"),
    (["fill", "{gappy}", "-m", "no_such_method"], "unknown method"),
    (["fill", "{gappy}", "-m", "svt", "-p", "max_iter=-3"], "max_iter expected"),
    (["fill", "{gappy}", "-m", "linear", "-p", "oops"], "NAME=VALUE"),
    (["fill", "{gappy}", "--max-gap", "-1"], "max_gap expected"),
    (["evaluate", "{gappy}", "--gap-length", "1000"], "gap_length expected"),
])
def test_bad_input_is_one_line_and_exit_2(args, needle, gappy_npz, tmp_path, capsys):
    path, _ = gappy_npz
    (tmp_path / "x.xyz").write_text("nothing")
    names = {"missing": tmp_path / "absent.c3d", "bad_suffix": tmp_path / "x.xyz", "gappy": path}
    before = sorted(p.name for p in tmp_path.iterdir())
    code = main([a.format(**{k: str(v) for k, v in names.items()}) for a in args])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("torchfill: error:") and len(err.splitlines()) == 1
    assert needle in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_real_recording_info_and_evaluate(recording, capsys):
    path = recording("cmu_02_01.c3d")
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "frames 343 (numbered 50-392 as in the file), markers 41" in out
    assert main(["evaluate", str(path), "-m", "linear", "--markers", "5", "--gap-length", "40",
                 "--max-gaps", "2", "-q", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["results"][0]
    assert 0 < row["rmse"] < row["rmse_missing"] < 200  # mm; the all-entries RMSE is diluted


def test_threads_option_sets_torch_threads_and_refuses_zero(gappy_npz, tmp_path, capsys, monkeypatch):
    import torch

    path, _ = gappy_npz
    before = torch.get_num_threads()
    monkeypatch.setenv("OMP_NUM_THREADS", str(before))      # restored after the test
    out = tmp_path / "out.npz"
    try:
        assert main(["fill", str(path), "-o", str(out), "-m", "linear", "-q", "--threads", "1"]) == 0
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    assert main(["fill", str(path), "-o", str(tmp_path / "x.npz"), "-m", "linear",
                 "--threads", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["torchfill: error: --threads expected >= 1, found 0"]
    assert not (tmp_path / "x.npz").exists()


def test_fill_dtype_reaches_fill(gappy_npz, tmp_path):
    """``--dtype`` is fill()'s ``dtype``: the written fill is fill()'s in that dtype, observed
    samples as read either way; an unknown dtype is a usage error (exit 2)."""
    path, X = gappy_npz
    given = np.load(path)["points"]
    for dtype in ("float32", "float64"):
        out = tmp_path / f"{dtype}.npz"
        assert main(["fill", str(path), "-o", str(out), "-m", "svt", "-p", "max_iter=20", "-q",
                     "--dtype", dtype]) == 0
        Y = np.load(out)["points"]
        assert np.array_equal(Y, torchfill.fill(given, "svt", max_iter=20, dtype=dtype))
        assert Y.dtype == np.float64 and np.array_equal(Y[np.isfinite(X)], X[np.isfinite(X)])
    assert not np.array_equal(np.load(tmp_path / "float32.npz")["points"],
                              np.load(tmp_path / "float64.npz")["points"])
    with pytest.raises(SystemExit) as err:
        main(["fill", str(path), "-o", str(tmp_path / "x.npz"), "--dtype", "float16"])
    assert err.value.code == 2


@pytest.mark.parametrize("verb", ["fill", "evaluate"])
@pytest.mark.parametrize("args, needle", [
    (["-m", "tuker"], "unknown method 'tuker'; did you mean 'tucker'?"),
    (["-m", "pchip,tuker"], "unknown method 'tuker'; did you mean 'tucker'?"),
    (["-m", "svt", "-p", "max_iters=100"], "no hyperparameter 'max_iters'; did you mean "
                                              "'max_iter'?"),
    (["-p", "seeds=1"], "no hyperparameter 'seeds'; did you mean 'seed'?"),
    (["-p", "max_iters=100"], "no hyperparameter 'max_iters'; 'max_iter' is a hyperparameter of "
                              "svt, trnn, trnn_d2, tucker and"),
])
def test_names_are_checked_before_any_work(verb, args, needle, gappy_npz, tmp_path, capsys):
    """A typo is named before the recording is read (nothing printed, nothing written)."""
    if verb == "fill" and "," in args[-1]:
        return                                         # fill takes one method
    out = ["-o", str(tmp_path / "out.npz")] if verb == "fill" else []
    code = main([verb, str(gappy_npz[0]), *out, *args])
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and needle in err, err
    assert captured.out == "" and not (tmp_path / "out.npz").exists()


def test_method_names_forgive_case(gappy_npz, tmp_path, capsys):
    path, X = gappy_npz
    assert main(["fill", str(path), "-o", str(tmp_path / "a.npz"), "-m", "LINEAR", "-q"]) == 0
    assert main(["evaluate", str(path), "-m", "PCHIP,Linear", "--markers", "2", "--gap-length",
                 "20", "--max-gaps", "2", "--json", "-q"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [row["method"] for row in report["results"]] == ["pchip", "linear"]


def test_evaluate_recommends_and_warns_once(recording, capsys):
    """The reported file: the table ends with the best method and its margin; the trial-end
    warning the three fills share is printed once; one-shot methods show no iteration count."""
    path = recording("c3dorg_s26_walking_hybrid_1_1.c3d")
    assert main(["evaluate", str(path), "-m", "linear,spline,pchip"]) == 0
    captured = capsys.readouterr()
    out = captured.out.strip().splitlines()
    rows = {line.split()[0]: line.split() for line in out if line.split()[0] in
            ("linear", "spline", "pchip")}
    gaps = {m: float(r[4]) for m, r in rows.items()}
    best = min(gaps, key=gaps.get)
    second = sorted(gaps.values())[1]
    assert out[-1].startswith(f"best on this file: {best} (rmse over the gaps {gaps[best]:.4g} mm")
    assert f"{second - gaps[best]:.3g} mm" in out[-1]
    assert all(r[-1] == "-" for r in rows.values())            # no "1 iteration"
    warnings_ = [line for line in captured.err.splitlines() if "warning" in line]
    assert len(warnings_) == len(set(w.split(":")[2] for w in warnings_)) >= 1
    assert "the fills of linear, spline, pchip" in warnings_[0]


def test_fill_trc_for_opensim(gappy_npz, tmp_path, capsys):
    """--axes/--units turn and scale every sample of a TRC output; other outputs refuse them."""
    path, X = gappy_npz
    out = tmp_path / "opensim.trc"
    assert main(["fill", str(path), "-o", str(out), "-m", "linear", "-q", "--axes", "x,z,-y",
                 "--units", "m"]) == 0
    back = torchfill.read(out)
    assert back.units == "m" and out.read_text().splitlines()[0].endswith("opensim.trc")
    lab = back.with_axes("x,-z,y").in_units("mm")
    observed = np.isfinite(X).all(axis=2)
    np.testing.assert_allclose(lab.points[observed], X[observed], rtol=1e-12)
    assert main(["fill", str(path), "-o", str(tmp_path / "x.npz"), "--units", "m"]) == 2
    assert main(["fill", str(path), "-o", str(tmp_path / "x.trc"), "--axes", "up"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "--axes/--units write TRC files" in err[0] and "signed permutation" in err[1]
