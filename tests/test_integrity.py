"""The integrity holes and rough edges a new user hit, one regression test per class.

Each test reproduces the failure on the code before the fix (see the commit messages) and checks
the rule it broke: observed samples never change in any output, a written file keeps what the
input had, bad input gives one line ``torchfill: error: <file>: <problem>`` with exit 2 and
nothing written.
"""
from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill import cli
from torchfill.io import FileFormatError
from torchfill.sequence import MarkerSequence

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}


def _seq(T=40, J=4, seed=0, labels=None):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None, None]
    points = 300 + 100 * np.sin(2 * np.pi * t + rng.uniform(0, 6, (1, J, 3)))
    points[10:15, 1] = np.nan
    return MarkerSequence(points=points, labels=labels or [f"M{j}" for j in range(J)], rate=100.0)


def _int16_c3d(path: Path, points: np.ndarray, scale: float = 0.1, labels=None) -> Path:
    """An Intel int16 C3D (POINT:SCALE > 0) written with the c3d package; NaN = invalid."""
    import c3d as c3d_package
    T, J, _ = points.shape
    writer = c3d_package.Writer(point_rate=100.0, analog_rate=0.0, point_scale=scale,
                                point_units="mm")
    writer.set_point_labels(labels or [f"M{j}" for j in range(J)])
    frames = np.zeros((T, J, 5), np.float32)
    ok = np.isfinite(points).all(axis=2)
    frames[..., :3] = np.where(ok[..., None], points, 0)
    frames[..., 3] = np.where(ok, 0.0, -1.0)
    writer.add_frames([(frames[t], np.zeros((0, 1), np.float32)) for t in range(T)])
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        writer.write(buf)
    path.write_bytes(buf.getvalue())
    return path


def _run_cli(argv, capsys):
    status = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    return status, out.out, out.err


def _one_line_error(err: str, name: str) -> None:
    lines = [line for line in err.splitlines() if not line.startswith("torchfill: warning")]
    assert len(lines) == 1, err
    assert lines[0].startswith("torchfill: error: ") and name in lines[0], err


# -- 1. non-ASCII labels ---------------------------------------------------------------------
def test_class01_non_ascii_labels_survive_c3d_and_trc(tmp_path):
    labels = ["Épaule", "肘", "M2", "M3"]
    seq = _seq(labels=labels)
    for name in ("fresh.c3d", "fresh.trc", "fresh.csv", "fresh.npz"):
        torchfill.write(seq, tmp_path / name)
        back = torchfill.read(tmp_path / name)
        assert back.labels == labels, name
    # a UTF-8 TRC written by another program is read as UTF-8, not Latin-1
    text = (tmp_path / "fresh.trc").read_text(encoding="utf-8")
    (tmp_path / "other.trc").write_bytes(text.encode("utf-8"))
    assert torchfill.read(tmp_path / "other.trc").labels == labels
    # and a fill written back keeps its bytes outside the filled cells
    out = torchfill.fill(torchfill.read(tmp_path / "other.trc"), "linear")
    torchfill.write(out, tmp_path / "back.trc")
    assert torchfill.read(tmp_path / "back.trc").labels == labels


# -- 2. TRC write-back of a partly missing sample ------------------------------------------
def _trc_text(rows: list[list[str]], labels=("A", "B")) -> str:
    J = len(labels)
    head = ["PathFileType\t4\t(X/Y/Z)\tx.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
            "OrigDataStartFrame\tOrigNumFrames",
            f"100\t100\t{len(rows)}\t{J}\tmm\t100\t1\t{len(rows)}",
            "Frame#\tTime\t" + "\t\t\t".join(labels),
            "\t\t" + "\t".join(f"X{j + 1}\tY{j + 1}\tZ{j + 1}" for j in range(J)), ""]
    body = [f"{t + 1}\t{t / 100:.3f}\t" + "\t".join(r) for t, r in enumerate(rows)]
    return "\n".join(head + body) + "\n"


def test_class02_trc_write_back_keeps_observed_cells_of_partial_samples(tmp_path):
    rows = [[f"{600 + t:.5f}", f"{10 + t:.5f}", f"{20 + t:.5f}", "1.00000", "2.00000", "3.00000"]
            for t in range(6)]
    rows[2][:3] = ["6.515494612345e+02", "", ""]           # x observed, y and z missing
    path = tmp_path / "partial.trc"
    path.write_text(_trc_text(rows))
    out = torchfill.fill(torchfill.read(path), "linear")
    torchfill.write(out, tmp_path / "out.trc")
    cells = (tmp_path / "out.trc").read_text().splitlines()[6 + 2].split("\t")
    assert cells[2] == "6.515494612345e+02"
    assert cells[3] and cells[4]                            # y and z filled


# -- 3. fill(mask=...) and write-back agree ------------------------------------------------
def test_class03_masked_samples_are_written_back(tmp_path):
    path = tmp_path / "src.trc"
    torchfill.write(_seq(), path)
    seq = torchfill.read(path)
    mask = np.zeros(seq.mask.shape, bool)
    mask[20:25, 0] = True                                   # observed samples, forced missing
    out = torchfill.fill(seq, "linear", mask=mask)
    assert out.meta["filled"][20:25, 0].all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")                      # no "differ ... not written" warning
        torchfill.write(out, tmp_path / "out.trc")
    back = torchfill.read(tmp_path / "out.trc")
    np.testing.assert_allclose(back.points[20:25, 0], out.points[20:25, 0], atol=1e-6)


# -- 4. a filled sample at exactly (0, 0, 0); huge observed values ------------------------
def test_class04_filled_sample_at_the_origin_stays_filled(tmp_path):
    T = 11
    pts = np.zeros((T, 2, 3))
    pts[:, 0] = np.linspace(-5, 5, T)[:, None]              # crosses (0, 0, 0) at frame 5
    pts[:, 1] = 100.0
    pts[3:8, 0] = np.nan
    for name in ("zero.c3d", "zero.trc"):
        src = tmp_path / f"src_{name}"
        if name.endswith(".c3d"):
            _int16_c3d(src, pts)
        else:
            torchfill.write(MarkerSequence(points=pts, labels=["A", "B"]), src)
        out = torchfill.fill(torchfill.read(src), "linear")
        assert not out.mask.any()
        torchfill.write(out, tmp_path / name)
        back = torchfill.read(tmp_path / name)
        assert not back.mask.any(), name                     # 0 left unfilled, as the CLI says
        np.testing.assert_allclose(back.points[5, 0], 0.0, atol=0.11)


def test_class04_huge_observed_value_does_not_move_other_fills():
    seq = _seq(T=60, J=5)
    clean = torchfill.fill(seq.points, "svt")
    bad = seq.points.copy()
    bad[30, 3, 0] = 1e18                                    # one corrupt observed coordinate
    with pytest.warns(UserWarning, match="huge"):
        out = torchfill.fill(bad, "svt")
    assert out[30, 3, 0] == 1e18                             # observed: kept bit-for-bit
    np.testing.assert_allclose(out[10:15, 1], clean[10:15, 1], rtol=1e-3)


# -- 5. corrupt .npz / .csv / .npy ---------------------------------------------------------
def _corrupt_array_files(tmp_path: Path) -> list[Path]:
    good = tmp_path / "good.npz"
    torchfill.write(_seq(), good)
    raw = good.read_bytes()
    files = []
    (tmp_path / "trunc.npz").write_bytes(raw[:len(raw) // 2]); files.append(tmp_path / "trunc.npz")
    k = raw.index(b"\x93NUMPY") + 200                        # inside the first member's data
    crc = bytearray(raw); crc[k] ^= 0xFF
    (tmp_path / "crc.npz").write_bytes(bytes(crc)); files.append(tmp_path / "crc.npz")
    with zipfile.ZipFile(tmp_path / "garbage.npz", "w") as z:
        z.writestr("points.npy", b"this is not an array")
    files.append(tmp_path / "garbage.npz")
    (tmp_path / "digits.csv").write_text("1,2," + "9" * 200_000 + "\n4,5,6\n")
    files.append(tmp_path / "digits.csv")
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (100000000000, 3, 3), }"
    header += " " * (117 - len(header)) + "\n"
    (tmp_path / "huge.npy").write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little")
                                        + header.encode() + b"\x00" * 64)
    files.append(tmp_path / "huge.npy")
    return files


def test_class05_corrupt_array_files_give_one_line_errors(tmp_path, capsys):
    for path in _corrupt_array_files(tmp_path):
        status, _, err = _run_cli(["info", path], capsys)
        assert status == 2, (path.name, err)
        _one_line_error(err, path.name)


# -- 6. fresh C3D with > 255 markers and a label > 255 characters --------------------------
def test_class06_fresh_c3d_many_markers_and_long_label(tmp_path):
    J = 300
    labels = [f"P{j}" for j in range(J)]
    labels[7] = "L" * 300
    seq = MarkerSequence(points=np.random.default_rng(0).normal(0, 100, (5, J, 3)), labels=labels)
    with pytest.warns(UserWarning, match="255"):
        torchfill.write(seq, tmp_path / "wide.c3d")
    back = torchfill.read(tmp_path / "wide.c3d")
    assert back.n_markers == J and back.labels[:7] == labels[:7] and back.labels[8:] == labels[8:]
    assert back.labels[7] == "L" * 255
    np.testing.assert_array_equal(back.points, seq.points.astype(np.float32))


# -- 7. killed during the write ------------------------------------------------------------
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_class07_killed_writer_leaves_no_temporary_file(tmp_path, sig):
    code = ("import sys, time; from pathlib import Path; from torchfill.io._common import "
            "atomic_write\n"
            "def slow(h):\n    h.write(b'x' * 1000); h.flush(); print('writing', flush=True); "
            "time.sleep(30)\n"
            "from torchfill import cli; cli._install_signal_handlers()\n"
            f"atomic_write(Path({str(tmp_path / 'out.c3d')!r}), slow)\n")
    proc = subprocess.Popen([PY, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=ENV, cwd=REPO)
    assert proc.stdout.readline().strip() == b"writing"
    proc.send_signal(sig)
    proc.wait(timeout=30)
    assert list(tmp_path.iterdir()) == []


# -- 8. Ctrl-C during start-up -------------------------------------------------------------
def test_class08_interrupt_during_startup_prints_no_traceback(tmp_path):
    lazy = subprocess.run([PY, "-c", "import sys, torchfill.cli; print('torch' in sys.modules)"],
                          capture_output=True, text=True, env=ENV, cwd=REPO)
    assert lazy.stdout.strip() == "False", lazy.stderr       # the heavy imports come later
    for delay in (0.6, 1.2, 2.0):
        proc = subprocess.Popen([PY, "-m", "torchfill", "methods"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, env=ENV, cwd=REPO)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert b"Traceback" not in err, err.decode()


# -- 9. read-only output -------------------------------------------------------------------
def test_class09_read_only_output_is_not_replaced(tmp_path, capsys):
    src = tmp_path / "in.npz"
    torchfill.write(_seq(), src)
    out = tmp_path / "out.npz"
    out.write_bytes(b"keep me")
    out.chmod(0o444)
    status, _, err = _run_cli(["fill", src, "-o", out, "-m", "linear", "-q"], capsys)
    assert status == 2
    _one_line_error(err, "out.npz")
    assert out.read_bytes() == b"keep me"


# -- 10. TRC numbers that overflow ---------------------------------------------------------
def test_class10_trc_overflow_is_an_error(tmp_path, capsys):
    rows = [["1.0", "2.0", "3.0"] for _ in range(4)]
    rows[2][1] = "1e400"
    path = tmp_path / "over.trc"
    path.write_text(_trc_text(rows, labels=("A",)))
    with pytest.raises(FileFormatError, match="line 9"):
        torchfill.read(path)
    status, _, err = _run_cli(["info", path], capsys)
    assert status == 2
    _one_line_error(err, "over.trc")


# -- 11. labels of fresh TRC / CSV ---------------------------------------------------------
@pytest.mark.parametrize("suffix", [".trc", ".csv"])
def test_class11_fresh_trc_csv_keep_labels_or_say_so(tmp_path, suffix):
    labels = ["a,b", 'q"uote', "dup", "dup", "tab\there", " pad ", "", "R.X"]
    seq = MarkerSequence(points=np.arange(3 * 8 * 3, dtype=float).reshape(3, 8, 3) + 1,
                         labels=labels)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torchfill.write(seq, tmp_path / f"l{suffix}")
    said = " ".join(str(w.message) for w in caught)
    back = torchfill.read(tmp_path / f"l{suffix}")
    assert back.n_markers == 8
    np.testing.assert_array_equal(back.points, seq.points)
    for want, got in zip(labels, back.labels):
        assert want == got or repr(want) in said, (want, got, said)
    assert "duplicate" in said


# -- 12. broken pipe -----------------------------------------------------------------------
def test_class12_broken_pipe_is_silent(tmp_path):
    path = tmp_path / "many.npz"
    J = 3000
    torchfill.write(MarkerSequence(points=np.ones((3, J, 3)), labels=[f"marker_{j:05d}" for j
                                                                      in range(J)]), path)
    proc = subprocess.Popen([PY, "-m", "torchfill", "info", str(path), "--all-markers"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, cwd=REPO)
    proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read()
    proc.wait(timeout=60)
    assert err == b"", err.decode()


# -- 13. an empty method name --------------------------------------------------------------
def test_class13_empty_method_is_an_error(tmp_path, capsys):
    src = tmp_path / "in.npz"
    torchfill.write(_seq(), src)
    status, _, err = _run_cli(["fill", src, "-o", tmp_path / "o.npz", "-m", ""], capsys)
    assert status == 2
    _one_line_error(err, "in.npz")
    assert not (tmp_path / "o.npz").exists()
    with pytest.raises(ValueError, match="method"):
        torchfill.fill(_seq(), "")


# -- errors that did not name the file -----------------------------------------------------
def test_errors_name_the_file(tmp_path, capsys):
    one = tmp_path / "one.npz"
    torchfill.write(MarkerSequence(points=np.ones((1, 2, 3)), labels=["a", "b"]), one)
    src = tmp_path / "in.npz"
    torchfill.write(_seq(), src)
    zero = tmp_path / "zero.trc"
    zero.write_text(_trc_text([[] for _ in range(3)], labels=()))
    cases = [(["fill", one, "-m", "linear"], "one.npz"),
             (["fill", src, "-m", "no_such_method"], "in.npz"),
             (["fill", src, "-m", "svt", "-p", "bogus=1"], "in.npz"),
             (["fill", src, "-m", "linear", "--max-gap", "-5"], "in.npz"),
             (["info", zero], "zero.trc")]
    for argv, name in cases:
        status, _, err = _run_cli(argv + ["-q"] if argv[0] == "fill" else argv, capsys)
        assert status == 2, argv
        _one_line_error(err, name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npz", "one.npz", "zero.trc"]


def test_fresh_trc_and_csv_keep_observed_values_exactly(tmp_path):
    seq = _seq()
    seq.points[3, 0, 0] = 6.515494612345e+02
    for name in ("f.trc", "f.csv", "f.npz"):
        torchfill.write(seq, tmp_path / name)
        back = torchfill.read(tmp_path / name)
        np.testing.assert_array_equal(back.points, seq.points)


def test_param_values_as_methods_v_shows_them(tmp_path, capsys):
    """Real-file usability: -p verbose=True and -p rank=(8,8,3) failed; only JSON worked."""
    assert cli._parse_params(["verbose=True", "rank=(8,8,3)", "tol=1e-5", "x=None", "s=abc",
                              "j=[1, 2]", "b=true"]) == {
        "verbose": True, "rank": (8, 8, 3), "tol": 1e-5, "x": None, "s": "abc", "j": [1, 2],
        "b": True}
    src = tmp_path / "in.npz"
    torchfill.write(_seq(), src)
    status, _, err = _run_cli(["fill", src, "-o", tmp_path / "o.npz", "-m", "grad_tucker",
                               "-p", "rank=(3,3,3)", "-p", "max_iter=5", "-q"], capsys)
    assert status == 0, err


DATA = Path(os.environ.get("TORCHFILL_DATA") or REPO / ".." / "shared" / "data").resolve()


def _real(name: str) -> Path:
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"shared recording {name} not found")
    return path


def test_evaluate_works_on_real_gapped_files_in_mm(capsys):
    """Before: refused files without 2 complete markers, printed metre files in metres, and
    counted duplicate labels as separate markers."""
    import json
    argv = ["-m", "linear", "--markers", "5", "--gap-length", "30", "--max-gaps", "2", "--json"]
    no_complete = _real("c3dorg_s26_walking_hybrid_1_1.c3d")      # 0 complete markers
    assert cli.main(["evaluate", str(no_complete), *argv]) == 0
    out = capsys.readouterr()
    row = json.loads(out.out)["results"][0]
    assert 0 < row["rmse_missing"] < 200
    metres = _real("ktk_basket_sprint.c3d")                          # units m, 0 complete
    assert cli.main(["evaluate", str(metres), *argv]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["units"] == "mm" and 1 < report["results"][0]["rmse_missing"] < 500
    dups = _real("c3dorg_s26_walking_hybrid_2.c3d")                  # 25 duplicated labels
    assert cli.main(["evaluate", str(dups), *argv]) == 0
    out = capsys.readouterr()
    assert "duplicate-label marker(s) merged" in out.err
    assert json.loads(out.out)["results"][0]["rmse_missing"] > 1e-3   # not a copy's free fill


def test_info_separates_never_observed_markers_trial_ends_and_duplicates(tmp_path, capsys):
    points = np.ones((50, 4, 3)) + np.arange(50)[:, None, None]
    points[:, 3] = np.nan                                   # never observed
    points[0:5, 0] = np.nan                                 # at the start
    points[20:23, 1] = np.nan                               # interior, 3 frames
    points[30, :] = np.nan                                  # no marker seen
    path = tmp_path / "i.npz"
    torchfill.write(MarkerSequence(points=points, labels=["A", "B", "B", "D"]), path)
    assert cli.main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "longest 5 frames" in out                         # not 50 (the never-seen marker)
    assert "interior gap(s) (longest 3 frames), 1 at the trial ends" in out
    assert "1 frame(s) with no marker seen" in out
    assert "1 marker(s) never observed: D" in out
    assert "duplicate labels: B (markers 1, 2)" in out
    assert f"{100 * (6 + 4 + 1) / 150:.1f}% missing in observed markers" in out


def test_headerless_csv_says_what_it_assumed_and_the_fill_records_it(tmp_path):
    path = tmp_path / "raw.csv"
    path.write_text("1,2,3,4,5,6\n,,,7,8,9\n2,3,4,5,6,7\n")
    with pytest.warns(UserWarning, match="no header row; labels M1..M2, 100 Hz, mm assumed"):
        seq = torchfill.read(path)
    torchfill.write(seq, tmp_path / "same.csv")              # nothing filled: stays headerless
    lines = (tmp_path / "same.csv").read_text().splitlines()
    assert lines[1:] == ["1.0,2.0,3.0,4.0,5.0,6.0", ",,,7.0,8.0,9.0", "2.0,3.0,4.0,5.0,6.0,7.0"]
    out = torchfill.fill(seq, "linear")
    torchfill.write(out, tmp_path / "filled.csv")
    lines = (tmp_path / "filled.csv").read_text().splitlines()
    assert lines[0] == "# rate=100.0; units=mm; first_frame=0"
    assert lines[1] == "M1_x,M1_y,M1_z,M2_x,M2_y,M2_z,filled"   # the filled samples' column
    assert lines[2] == "1.0,2.0,3.0,4.0,5.0,6.0," and lines[3].endswith(",1")


def test_unwritable_output_is_refused_before_the_fill(tmp_path, capsys, monkeypatch):
    src = tmp_path / "in.npz"
    torchfill.write(_seq(), src)
    called = []
    monkeypatch.setattr(torchfill, "fill", lambda *a, **k: called.append(1))
    for out in (tmp_path / "o.xyz", tmp_path / "nope" / "o.npz"):
        status, _, err = _run_cli(["fill", src, "-o", out, "-m", "linear", "-q"], capsys)
        assert status == 2 and not called
        _one_line_error(err, out.name)
