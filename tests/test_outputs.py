"""The one guarded writer (torchfill/io/outputs.py): no output lands on a file the run reads or on
another output of the run, whatever the spelling (./a, a, dir/../a, a symlinked folder, a hard
link); folders are checked before any work; a write is atomic (a full disk, an error or a signal
leaves the old file as it was and no temporary file); a planted symlink is replaced, never followed;
a write-back uses the bytes read at the start."""
from __future__ import annotations

import errno
import os
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill.io import FileFormatError
from torchfill.io.outputs import Outputs, make_folder, sweep


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.name: (p.read_bytes() if p.is_file() and not p.is_symlink() else b"")
            for p in sorted(folder.iterdir())}


def _seq(walk, T=120, J=5):
    X = walk(T, J, seed=3)
    X[30:50, 1] = np.nan
    X[70:75, 3] = np.nan
    return torchfill.MarkerSequence(points=X, labels=[f"M{j}" for j in range(J)], rate=100.0)


def test_an_input_is_caught_by_every_spelling(tmp_path, monkeypatch):
    src = tmp_path / "a.c3d"
    src.write_bytes(b"recording")
    (tmp_path / "sub").mkdir()
    os.link(src, tmp_path / "hard.c3d")
    os.symlink(tmp_path, tmp_path / "via")
    monkeypatch.chdir(tmp_path)
    run = Outputs()
    run.add_input("a.c3d")
    for spelling in ["a.c3d", "./a.c3d", "sub/../a.c3d", str(src), "via/a.c3d", "hard.c3d"]:
        with pytest.raises(FileFormatError, match="would overwrite the input"):
            run.add_output(spelling)
    assert run.add_output("a.c3d", replace_input=True) == Path("a.c3d")   # --in-place only
    assert src.read_bytes() == b"recording"


def test_training_files_and_other_outputs_are_guarded(tmp_path):
    run = Outputs()
    (tmp_path / "t.c3d").write_bytes(b"training")
    run.add_input(tmp_path / "t.c3d", "training")
    with pytest.raises(FileFormatError, match="overwrite the training"):
        run.add_output(tmp_path / "t.c3d", replace_input=True)        # in-place: inputs only
    run.add_output(tmp_path / "o.c3d")
    with pytest.raises(FileFormatError, match="overwrite the output .*o.c3d of this run"):
        run.add_output(tmp_path / "." / "o.c3d", "report")


def test_folders_are_checked_before_any_work(tmp_path):
    run = Outputs()
    (tmp_path / "file").write_text("x")
    os.symlink("loop", tmp_path / "loop")
    (tmp_path / "dir").mkdir()
    ro = tmp_path / "ro.csv"
    ro.write_text("old")
    ro.chmod(0o444)
    cases = {tmp_path / "missing" / "o.c3d": "does not exist",
             tmp_path / "file" / "o.c3d": "not a folder",
             tmp_path / "loop" / "o.c3d": "symbolic link loop",
             tmp_path / "dir": "existing folder",
             ro: "read-only"}
    for path, needle in cases.items():
        with pytest.raises(FileFormatError, match=needle):
            run.add_output(path)
    with pytest.raises(FileFormatError, match="symbolic link loop"):
        make_folder(tmp_path / "loop")
    with pytest.raises(FileFormatError, match="not a folder"):
        make_folder(tmp_path / "file" / "sub")


def test_a_full_disk_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "report.html"
    target.write_text("the old report")
    real_fsync = os.fsync

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", full)
    with Outputs() as run, pytest.raises(FileFormatError, match="No space left.*unchanged"):
        run.write_text(target, "<html>" + "x" * 100_000)
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert _listing(tmp_path) == {"report.html": b"the old report"}


def test_a_real_full_file_system_leaves_the_old_file(tmp_path, walk):
    """A 64 KiB tmpfs (needs permission to mount; skipped otherwise)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
                          capture_output=True)
    if done.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        old = mnt / "out.csv"
        old.write_text("frame,M0\n0,1\n")
        before = old.read_bytes()
        big = torchfill.MarkerSequence(points=walk(4000, 8), labels=[f"M{j}" for j in range(8)])
        with Outputs() as run, pytest.raises(FileFormatError, match="No space left"):
            run.write_sequence(big, old)
        assert old.read_bytes() == before
        assert sorted(p.name for p in mnt.iterdir()) == ["out.csv"]
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_an_error_while_serialising_leaves_nothing(tmp_path):
    def fails(tmp: Path):
        tmp.write_bytes(b"half")
        raise KeyboardInterrupt
    with Outputs() as run, pytest.raises(KeyboardInterrupt):
        run.write(tmp_path / "o.c3d", fails)
    assert list(tmp_path.iterdir()) == []


def test_a_planted_symlink_is_replaced_not_followed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    link = tmp_path / "report.html"
    os.symlink(victim, link)
    with Outputs() as run:
        run.write_text(link, "<html>report</html>")
    assert victim.read_text() == "precious"
    assert not link.is_symlink() and link.read_text() == "<html>report</html>"


def test_a_new_file_gets_the_replaced_files_mode(tmp_path):
    target = tmp_path / "o.csv"
    target.write_text("old")
    target.chmod(0o640)
    with Outputs() as run:
        run.write_text(target, "new")
    assert target.stat().st_mode & 0o777 == 0o640 and target.read_text() == "new"


def test_writer_messages_name_the_target_not_the_temporary(tmp_path, walk):
    seq = torchfill.MarkerSequence(points=walk(20, 2), labels=["a", "a"])   # duplicates: a warning
    with Outputs() as run, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run.write_sequence(seq, tmp_path / "o.csv")
    texts = " ".join(str(w.message) for w in caught)
    assert "o.csv" in texts and "torchfill-" not in texts


def test_write_back_uses_the_bytes_read_at_the_start(tmp_path, walk):
    """A source replaced during the fill: the output is built from what was read, and says so."""
    src = tmp_path / "a.c3d"
    torchfill.write(_seq(walk), src)
    with Outputs() as run:
        run.add_input(src, template=True)
        run.keep_templates()
        seq = torchfill.read(src)
        run.confirm_inputs()
        filled = torchfill.fill(seq, "linear")
        other = seq.with_points(seq.points + 400.0)          # someone rewrites the source
        other.source = None
        torchfill.write(other, src)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            run.write_sequence(filled, tmp_path / "out.c3d")
    assert any("changed on disk during the fill" in str(w.message) for w in caught)
    back = torchfill.read(tmp_path / "out.c3d")
    seen = ~seq.mask
    np.testing.assert_array_equal(back.points[seen], seq.points[seen])   # the original, not +400
    assert not back.mask.any()


def test_a_source_that_changes_while_read_is_refused(tmp_path, walk):
    src = tmp_path / "a.npz"
    torchfill.write(_seq(walk), src)
    run = Outputs()
    run.add_input(src, template=True)
    run.keep_templates()
    os.utime(src, ns=(1, 1))                                  # touched between copy and read
    with pytest.raises(FileFormatError, match="changed while it was being read"):
        run.confirm_inputs()
    run.close()


def test_sweep_removes_what_a_killed_write_left(tmp_path):
    left = tmp_path / ".o.c3d.torchfill-abc123"
    left.mkdir()
    (left / "o.c3d").write_bytes(b"partial")
    keep = tmp_path / ".other.c3d.torchfill-abc123"
    keep.mkdir()
    sweep(tmp_path / "o.c3d")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.c3d.torchfill-abc123"]


def test_a_run_is_all_or_nothing(tmp_path):
    """A side output that cannot be written leaves no main output behind, and the old files."""
    old = tmp_path / "old.csv"
    old.write_text("yesterday")

    def fail(tmp):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    with pytest.raises(FileFormatError, match="No space left.*nothing written"):
        with Outputs() as run:
            run.write_text(tmp_path / "main.csv", "the fill")
            run.write_text(old, "today")
            run.write(tmp_path / "side.html", fail)
    assert _listing(tmp_path) == {"old.csv": b"yesterday"}
    with Outputs() as run:                          # and all of it when nothing fails
        run.write_text(tmp_path / "main.csv", "the fill")
        run.write_text(old, "today")
        assert (old.read_text(), (tmp_path / "main.csv").exists()) == ("yesterday", False)
    assert _listing(tmp_path) == {"main.csv": b"the fill", "old.csv": b"today"}


def test_a_failed_rename_gives_the_old_files_back(tmp_path, monkeypatch):
    first, second = tmp_path / "a.csv", tmp_path / "b.csv"
    first.write_text("old a")
    real = os.replace

    def replace(src, dst):
        if str(dst).endswith("b.csv"):
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return real(src, dst)
    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(FileFormatError, match="b.csv: cannot write.*nothing written"):
        with Outputs() as run:
            run.write_text(first, "new a")
            run.write_text(second, "new b")
    assert _listing(tmp_path) == {"a.csv": b"old a"}


def test_write_refuses_a_source_changed_since_it_was_read(tmp_path, walk):
    src = tmp_path / "a.c3d"
    torchfill.write(_seq(walk), src)
    seq = torchfill.read(src)
    filled = torchfill.fill(seq, "linear")
    other = _seq(walk)
    other.points[...] += 495.0
    torchfill.write(other, src)                     # a re-export replaces the recording
    out = tmp_path / "o.c3d"
    with pytest.raises(FileFormatError, match="a.c3d: changed on disk since it was read"):
        torchfill.write(filled, out)
    assert not out.exists()
    torchfill.write(filled, tmp_path / "o.npz")    # no write-back: the source is not used
    again = torchfill.fill(torchfill.read(src), "linear")
    torchfill.write(again, out)                     # read again: written
    assert np.allclose(torchfill.read(out).points, again.points, atol=1e-3)
