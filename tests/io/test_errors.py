"""Bad input: one FileFormatError with a one-line message naming the file, nothing written."""
from __future__ import annotations

import numpy as np
import pytest

import torchfill
from torchfill.io import FileFormatError

from iohelpers import synthetic


def _fresh_c3d(tmp_path):
    path = tmp_path / "good.c3d"
    torchfill.write(synthetic(), path)
    return path


def _bad_files(tmp_path):
    """(path, expected message fragment) for every kind of bad input."""
    c3d_bytes = _fresh_c3d(tmp_path).read_bytes()
    cases = []

    def add(name, content, fragment):
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        cases.append((path, fragment))

    add("empty.c3d", b"", "empty file")
    add("truncated.c3d", c3d_bytes[:len(c3d_bytes) // 2], "truncated C3D")
    add("header_only.c3d", c3d_bytes[:600], "truncated C3D")
    add("text.c3d", b"frame,x,y,z\n1,2,3,4\n" * 40, "not a C3D file")
    add("missing.c3d", None, "no such file")
    add("empty.trc", b"", "empty file")
    add("text.trc", b"hello\nworld\n1\n2\n3\n4\n", "not a TRC file")
    add("letters.trc", b"PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tNumFrames\n100\t1\n"
        b"Frame#\tTime\tA\t\t\n\t\tX1\tY1\tZ1\n\n1\t0.0\t1\tabc\t3\n", "not a number")
    add("inf.trc", b"PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tNumFrames\n100\t1\n"
        b"Frame#\tTime\tA\t\t\n\t\tX1\tY1\tZ1\n\n1\t0.0\t1\tinf\t3\n", "infinite")
    add("empty.csv", b"", "empty file")
    add("text.csv", b"1,2,3\n4,five,6\n", "not a number")
    add("inf.csv", b"1,2,3\n4,inf,6\n", "infinite")
    add("shape.csv", b"1,2,3,4\n5,6,7,8\n", "wrong array shape")
    add("empty.npy", b"", "empty file")
    add("garbage.npy", b"\x93NUMPY garbage" * 10, "not a valid .npy")
    for name, array, fragment in [("shape.npy", np.zeros((10, 4)), "wrong array shape"),
                                  ("shape3.npy", np.zeros((10, 2, 4)), "wrong array shape"),
                                  ("vector.npy", np.zeros(9), "wrong array shape"),
                                  ("inf.npy", np.array([[[0.0, np.inf, 0.0]]] * 2), "infinite"),
                                  ("text.npy", np.array([["a", "b", "c"]]), "numeric")]:
        path = tmp_path / name
        np.save(path, array)
        cases.append((path, fragment))
    np.savez(tmp_path / "nopoints.npz", other=np.zeros((2, 3)))
    cases.append((tmp_path / "nopoints.npz", "no 'points'"))
    add("unknown.xyz", b"1 2 3", "unsupported file type")
    return cases


def test_every_bad_input_is_one_line(tmp_path):
    for path, fragment in _bad_files(tmp_path):
        with pytest.raises(FileFormatError) as err:
            torchfill.read(path)
        message = str(err.value)
        assert "\n" not in message, message
        assert path.name in message and fragment in message, (path.name, message)


def test_bad_input_through_the_cli_is_one_line_and_nonzero(tmp_path, capsys):
    cli = pytest.importorskip("torchfill.cli")
    bad = tmp_path / "text.c3d"
    bad.write_text("not a c3d\n" * 100)
    out = tmp_path / "out.c3d"
    code = cli.main(["fill", str(bad), "-o", str(out), "--method", "linear"])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "text.c3d" in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("suffix", [".c3d", ".trc", ".npy", ".npz", ".csv"])
def test_infinite_points_are_not_written(suffix, tmp_path):
    seq = synthetic()
    seq.points[3, 1, 2] = np.inf
    out = tmp_path / f"out{suffix}"
    with pytest.raises(FileFormatError, match="infinite"):
        torchfill.write(seq, out)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_no_partial_file(tmp_path, monkeypatch):
    """An error in the middle of writing removes the temporary file and keeps the old target."""
    out = tmp_path / "target.npy"
    out.write_bytes(b"old content")

    def broken_save(handle, *args, **kwargs):
        handle.write(b"partial")
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(np, "save", broken_save)
    with pytest.raises(RuntimeError):
        torchfill.write(synthetic(), out)
    assert out.read_bytes() == b"old content"
    assert [p.name for p in tmp_path.iterdir()] == ["target.npy"]


def test_write_to_missing_folder(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist"):
        torchfill.write(synthetic(), tmp_path / "nope" / "out.c3d")


def test_write_back_needs_matching_frames(tmp_path):
    src = _fresh_c3d(tmp_path)
    seq = torchfill.read(src)
    shorter = seq.select(range(seq.n_markers))
    shorter.points = shorter.points[:10]
    with pytest.raises(FileFormatError, match="cannot write back"):
        torchfill.write(shorter, tmp_path / "out.c3d")
    assert not (tmp_path / "out.c3d").exists()


def test_unsupported_processor_is_reported(tmp_path):
    src = _fresh_c3d(tmp_path)
    data = bytearray(src.read_bytes())
    data[(data[0] - 1) * 512 + 3] = 99
    bad = tmp_path / "proc.c3d"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="processor type 99"):
        torchfill.read(bad)
