"""Nothing a user owns is lost through the command line, and bad arguments fail at once.

One test (or a few) per class of failure: outputs and side outputs landing on an input, a training
file or each other; --in-place; side outputs written atomically (full disk, planted symlink,
missing folder found before the fill); a source replaced during the fill; batches with --out-dir
on a training folder, Ctrl-C, a killed worker, per-file options and warning texts; arguments
checked before any file is read; control characters in labels, units and file names; experiment
names; an --out-dir that is a symbolic link loop. The adversarial inputs are made in each test.
The CLI runs in-process (fast) except where exit codes and signals need a real process.
"""
from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill.cli import main

REPO = Path(__file__).resolve().parents[1]


def _recording(path: Path, walk, T=150, J=5, seed=0, labels=None, units="mm") -> Path:
    X = walk(T, J, seed=seed)
    X[30:50, 1] = np.nan
    X[90:96, 3] = np.nan
    np.savez(path, points=X, labels=np.array(labels or [f"M{j}" for j in range(J)]),
             rate=100.0, units=units) if path.suffix == ".npz" else torchfill.write(
        torchfill.MarkerSequence(points=X, labels=labels or [f"M{j}" for j in range(J)]), path)
    return path


def _snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): (os.readlink(p) if p.is_symlink() else
                                         p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def _one_error(capsys, needle: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("torchfill: error:") and len(err.splitlines()) == 1, err
    assert needle in err, err
    return err


# -- outputs and side outputs on an input (#1) -----------------------------------------------------
def test_no_output_or_side_output_lands_on_an_input(tmp_path, walk, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _recording(tmp_path / "a.c3d", walk)
    _recording(tmp_path / "b.npz", walk, seed=1)
    os.link(tmp_path / "a.c3d", tmp_path / "hard.c3d")
    os.link(tmp_path / "a.c3d", tmp_path / "hard.html")       # a report's name, the input's file
    before = _snapshot(tmp_path)
    cases = [
        (["fill", "a.c3d", "-o", "a.c3d"], "would overwrite the input a.c3d"),
        (["fill", "a.c3d", "-o", "./a.c3d"], "would overwrite the input"),
        (["fill", "a.c3d", "-o", "hard.c3d"], "would overwrite the input"),
        (["fill", "a.c3d", "-o", "o.c3d", "--std", "a.c3d"], "--std writes .csv"),
        (["fill", "b.npz", "-o", "o.npz", "--std", "b.npz"], "--std writes .csv"),
        (["fill", "a.c3d", "-o", "o.c3d", "--report", "a.c3d"], "--report writes .html"),
        (["fill", "a.c3d", "-o", "o.c3d", "--report", "r.csv"],
         "--report writes .html, found .csv (the per-gap verdicts as JSON: --report-json"),
        (["fill", "a.c3d", "-o", "o.c3d", "--report", "hard.html"],
         "report would overwrite the input"),
        (["fill", "a.c3d", "-o", "o.c3d", "--report-json", "r.html"], "--report-json writes .json"),
        (["fill", "a.c3d", "b.npz", "--out-dir", "d", "--report", "{stem}.csv"],
         "--report writes .html"),
        (["fill", "a.c3d", "-o", "o.c3d", "--report", "r.html", "--std", "r.html"],
         "--std writes .csv"),
        (["fill", "a.c3d", "-o", "o.csv", "--std", "./o.csv"], "would overwrite the output"),
        (["fill", "a.c3d", "-m", "pca_train", "--training", "b.npz", "-o", "b.npz"],
         "would overwrite the training b.npz"),
        (["qc", "a.c3d", "b.npz", "-o", "a.c3d"], "qc -o writes .html, found .c3d"),
        (["qc", "a.c3d", "b.npz", "--json", "a.c3d"], "--json writes .json"),
        (["qc", "a.c3d", "b.npz", "-o", "hard.html"], "qc report would overwrite the input"),
    ]
    for argv, needle in cases:
        assert main(argv) == 2, argv
        _one_error(capsys, needle)
    assert _snapshot(tmp_path) == before                       # nothing written, nothing changed


def test_in_place_keeps_an_orig_copy_unless_no_backup(tmp_path, walk, capsys):
    src = _recording(tmp_path / "a.c3d", walk)
    raw = src.read_bytes()
    assert main(["fill", str(src), "--in-place", "-m", "linear", "-q"]) == 0
    orig = tmp_path / "a.orig.c3d"
    assert orig.read_bytes() == raw                            # the recording as it was
    filled = torchfill.read(src)
    first = torchfill.read(orig)
    assert not filled.mask[~first.mask].any()
    np.testing.assert_array_equal(filled.points[~first.mask], first.points[~first.mask])
    now = src.read_bytes()
    assert main(["fill", str(src), "--in-place", "-m", "linear"]) == 2      # would lose the .orig
    _one_error(capsys, "a.orig.c3d: exists")
    assert orig.read_bytes() == raw and src.read_bytes() == now
    other = _recording(tmp_path / "b.npz", walk)
    assert main(["fill", str(other), "--in-place", "--no-backup", "-m", "linear", "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.c3d", "a.orig.c3d", "b.npz"]
    assert not torchfill.read(other).mask.any()


# -- side outputs written safely (#2) --------------------------------------------------------------
def test_a_full_disk_keeps_the_old_report(tmp_path, walk, capsys, monkeypatch):
    src = _recording(tmp_path / "a.npz", walk)
    report = tmp_path / "r.html"
    report.write_text("the report of yesterday")
    real = os.fsync
    calls = []

    def fsync(fd):
        calls.append(fd)
        if os.readlink(f"/proc/self/fd/{fd}").endswith("r.html"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)
    monkeypatch.setattr(os, "fsync", fsync)
    code = main(["fill", str(src), "-o", str(tmp_path / "o.npz"), "--report", str(report),
                 "-m", "linear", "-q"])
    assert code == 2
    _one_error(capsys, "No space left on device")
    assert report.read_text() == "the report of yesterday"
    assert not (tmp_path / "o.npz").exists()                 # exit 2: nothing new on disk
    assert not [p for p in tmp_path.iterdir() if "torchfill-" in p.name]   # no temporary left


def test_a_planted_symlink_at_the_report_is_replaced(tmp_path, walk):
    src = _recording(tmp_path / "a.npz", walk)
    victim = tmp_path / "victim.txt"
    victim.write_text("do not touch")
    os.symlink(victim, tmp_path / "r.html")
    os.symlink(victim, tmp_path / "s.csv")
    assert main(["fill", str(src), "-o", str(tmp_path / "o.npz"), "--report",
                 str(tmp_path / "r.html"), "--std", str(tmp_path / "s.csv"), "-m", "linear",
                 "-q"]) == 0
    assert victim.read_text() == "do not touch"
    assert not (tmp_path / "r.html").is_symlink() and "<html" in (tmp_path / "r.html").read_text()
    assert (tmp_path / "s.csv").read_text().startswith("frame,")


def test_a_missing_report_folder_fails_before_the_fill(tmp_path, walk, capsys, monkeypatch):
    src = _recording(tmp_path / "a.npz", walk)
    monkeypatch.setattr(torchfill, "fill", lambda *a, **k: pytest.fail("the fill ran"))
    assert main(["fill", str(src), "-o", str(tmp_path / "o.npz"), "--report",
                 str(tmp_path / "no" / "r.html")]) == 2
    _one_error(capsys, "folder " + str(tmp_path / "no") + " does not exist")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


# -- write-back from the bytes read at the start (#3) ----------------------------------------------
def test_a_source_replaced_during_the_fill_does_not_leak_into_the_output(tmp_path, walk, capsys,
                                                                          monkeypatch):
    src = _recording(tmp_path / "a.c3d", walk)
    original = torchfill.read(src)
    real_fill = torchfill.fill

    def fill_while_someone_rewrites(seq, *args, **kwargs):
        moved = original.with_points(original.points + 495.0)
        moved.source = None
        torchfill.write(moved, src)                 # another program replaces the recording
        return real_fill(seq, *args, **kwargs)
    monkeypatch.setattr(torchfill, "fill", fill_while_someone_rewrites)
    out = tmp_path / "o.c3d"
    assert main(["fill", str(src), "-o", str(out), "-m", "linear", "-q"]) == 0
    err = capsys.readouterr().err
    assert "changed on disk during the fill" in err and "content read at the start" in err
    back = torchfill.read(out)
    seen = ~original.mask
    np.testing.assert_array_equal(back.points[seen], original.points[seen])


# -- batches (#4-6) --------------------------------------------------------------------------------
def test_batch_out_dir_on_a_training_folder_keeps_the_training_file(tmp_path, walk, capsys):
    train_dir = tmp_path / "train"
    train_dir.mkdir()
    training = _recording(train_dir / "s1.npz", walk, seed=5)
    inputs = tmp_path / "in"
    inputs.mkdir()
    _recording(inputs / "s1.npz", walk, seed=1)                # same name as the training file
    _recording(inputs / "s2.npz", walk, seed=2)
    before = training.read_bytes()
    code = main(["fill", str(inputs), "--out-dir", str(train_dir), "-m", "pca_train",
                 "--training", str(training)])
    assert code == 2
    _one_error(capsys, "would overwrite the training")
    assert training.read_bytes() == before and sorted(os.listdir(train_dir)) == ["s1.npz"]


def test_batch_honours_single_file_options_and_shows_warning_texts(tmp_path, walk, capsys):
    inputs = tmp_path / "in"
    inputs.mkdir()
    for k in range(2):
        X = walk(150, 5, seed=k)
        X[:40, 2] = np.nan                                      # a gap at the trial start
        X[60:70, 1] = np.nan
        np.savez(inputs / f"t{k}.npz", points=X, labels=np.array([f"M{j}" for j in range(5)]),
                 rate=100.0, units="mm")
    code = main(["fill", str(inputs), "--out-dir", str(tmp_path / "out"), "-m", "linear",
                 "--extrapolate", "0.1", "--report", str(tmp_path / "rep") + "/",
                 "--std", str(tmp_path / "{stem}_std.csv")])
    out = capsys.readouterr().out
    assert code == 0
    for k in range(2):
        single = tmp_path / f"single{k}.npz"
        assert main(["fill", str(inputs / f"t{k}.npz"), "-o", str(single), "-m", "linear",
                     "--extrapolate", "0.1", "--std", str(tmp_path / f"s{k}.csv"), "-q"]) == 0
        batch = torchfill.read(tmp_path / "out" / f"t{k}.npz")
        np.testing.assert_array_equal(batch.points, torchfill.read(single).points)
        assert batch.mask[:30, 2].all() and not batch.mask[40:, 2].any()   # 0.1 s: <= 10 frames
        assert "<html" in (tmp_path / "rep" / f"t{k}.qc.html").read_text()
        assert (tmp_path / f"t{k}_std.csv").read_text().startswith("frame,")
        names = [line for line in out.splitlines() if line.startswith(f"t{k}.npz -> ")]
        assert names and f"t{k}_std.csv" in names[0] and f"t{k}.qc.html" in names[0]
        texts = [line for line in out.splitlines() if line.startswith(f"t{k}.npz: warning: ")]
        assert len(texts) == len(set(texts)) >= 1
        assert any("beyond the extrapolation limit left NaN" in t for t in texts)


def _cli_env(tmp_path: Path, tag: str) -> dict:
    """A subprocess environment whose worker processes read files through a hook: a file named
    killme* kills its worker (SIGKILL, as the OOM killer does) every time, killonce* once."""
    hook = tmp_path / "hook"
    hook.mkdir(exist_ok=True)
    (hook / "sitecustomize.py").write_text(
        "import os, sys\n"
        "if '--multiprocessing-fork' in sys.argv:\n"
        "    import torchfill.io as _io\n"
        "    _real = _io.read\n"
        "    def read(path, **kw):\n"
        "        name = os.path.basename(str(path))\n"
        "        flag = os.path.join(os.environ['KILL_FLAGS'], name)\n"
        "        if name.startswith('killme') or (name.startswith('killonce')\n"
        "                                         and not os.path.exists(flag)):\n"
        "            open(flag, 'w').close()\n"
        "            os.kill(os.getpid(), 9)\n"
        "        return _real(path, **kw)\n"
        "    _io.read = read\n")
    (tmp_path / "flags").mkdir(exist_ok=True)
    return {**os.environ, "PYTHONPATH": f"{hook}{os.pathsep}{REPO}", "OMP_NUM_THREADS": "1",
            "KILL_FLAGS": str(tmp_path / "flags"), "TORCHFILL_TEST_TAG": tag}


def _tagged_processes(tag: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if f"TORCHFILL_TEST_TAG={tag}".encode() in (entry / "environ").read_bytes():
                found.append(int(entry.name))
        except OSError:
            pass
    return found


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_a_killed_worker_costs_only_its_file(tmp_path, walk):
    inputs = tmp_path / "in"
    inputs.mkdir()
    for k, name in enumerate(["a.npz", "killme.npz", "killonce.npz", "z.npz"]):
        _recording(inputs / name, walk, seed=k)
    tag = uuid.uuid4().hex
    done = subprocess.run([sys.executable, "-m", "torchfill", "fill", str(inputs), "--out-dir",
                           str(tmp_path / "out"), "-m", "linear", "--workers", "2", "-q"],
                          env=_cli_env(tmp_path, tag), capture_output=True, text=True, timeout=600)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    assert sorted(os.listdir(tmp_path / "out")) == ["a.npz", "killonce.npz", "z.npz"]
    errors = [line for line in done.stderr.splitlines() if line.startswith("torchfill: error:")]
    assert len(errors) == 1 and "killme.npz" in errors[0] and "killed by SIGKILL" in errors[0]
    for name in ("a.npz", "killonce.npz", "z.npz"):
        assert not torchfill.read(tmp_path / "out" / name).mask.any()
    assert _tagged_processes(tag) == []


def _as_from_a_terminal() -> None:
    """In the child before exec: SIGINT handled and unblocked, as a shell starts a foreground
    command (a test run started in the background, ``cmd &``, would hand SIG_IGN down, and a
    process that starts with SIGINT ignored never sees ^C)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_ctrl_c_stops_a_batch_at_once_and_leaves_no_worker(tmp_path, walk):
    inputs = tmp_path / "in"
    inputs.mkdir()
    for k in range(16):
        _recording(inputs / f"t{k:02d}.npz", walk, T=1500, J=12, seed=k)
    out = tmp_path / "out"
    tag = uuid.uuid4().hex
    proc = subprocess.Popen([sys.executable, "-m", "torchfill", "fill", str(inputs), "--out-dir",
                             str(out), "-m", "svt", "-p", "max_iter=300", "-p", "tol=0",
                             "--workers", "2", "-q"],
                            env=_cli_env(tmp_path, tag), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + 300
    while not (out.is_dir() and any(p.suffix == ".npz" for p in out.iterdir())):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)                 # what a terminal's ^C does: the group
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    lines = stderr.strip().splitlines()
    assert lines[-1].startswith("torchfill: interrupted:") and "Traceback" not in stderr
    assert _tagged_processes(tag) == []                # no worker left
    written = _snapshot(out)
    assert 1 <= len(written) < 16
    assert all(not name.startswith(".") for name in written)          # no temporary left
    for name in written:
        assert torchfill.read(out / name).points.shape == (1500, 12, 3)   # complete files only
    time.sleep(3.0)
    assert _snapshot(out) == written                   # nothing written after the exit


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_ctrl_c_stops_a_long_recording_in_worker_processes_and_leaves_no_worker(tmp_path, walk):
    """The later windows of a long recording run in worker processes (started at once here);
    ^C ends them and the fill, writes nothing, and no worker is left."""
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one core: the windows run in this process")
    X = walk(6000, 8)
    X[100:160, 1] = X[2500:2540, 3] = X[5000:5050, 5] = np.nan
    src = tmp_path / "long.npz"
    np.savez(src, points=X, labels=np.array([f"M{j}" for j in range(8)]), rate=100.0, units="mm")
    tag = uuid.uuid4().hex
    env = _cli_env(tmp_path, tag)
    hook = tmp_path / "hook" / "sitecustomize.py"
    hook.write_text(hook.read_text() + "if sys.argv[:1] == ['-m']:\n"
                    "    import torchfill.windows\n"
                    "    torchfill.windows.LAUNCH_AFTER = 0.0\n")
    out = tmp_path / "out.npz"
    proc = subprocess.Popen([sys.executable, "-m", "torchfill", "fill", str(src), "-o", str(out),
                             "-m", "svt", "-p", "max_iter=3000", "-p", "tol=0", "--window", "300",
                             "--threads", "2", "-q"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + 300
    while len(_tagged_processes(tag)) < 4:          # this one, the resource tracker, 2 workers
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(2.0)                                   # the workers at their windows
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == "torchfill: interrupted"
    assert "Traceback" not in stderr, stderr
    assert _tagged_processes(tag) == []
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == \
        ["flags", "hook", "long.npz"]


# -- every argument checked before any file is read (#7) -------------------------------------------
def test_bad_arguments_fail_before_any_file_is_read(tmp_path, walk, capsys, monkeypatch):
    src = _recording(tmp_path / "a.c3d", walk)
    (tmp_path / "dir").mkdir()
    folder = tmp_path / "many"
    folder.mkdir()
    for k in range(2):
        _recording(folder / f"r{k}.c3d", walk, seed=k)
    before = _snapshot(tmp_path)

    def no_read(*args, **kwargs):
        raise AssertionError("a file was read")
    monkeypatch.setattr(torchfill, "read", no_read)
    monkeypatch.setattr(torchfill.io, "read", no_read)
    cases = [
        (["fill", src, "-m", "tuckr"], "did you mean 'tucker'?"),
        (["fill", src, "-m", "svt", "-p", "max_itr=5"], "did you mean 'max_iter'?"),
        (["fill", src, "-m", "svt", "-p", "max_iter=-3"], "max_iter expected"),
        (["fill", src, "-m", "linear", "-p", "window=3"], "give it as --window"),
        (["fill", src, "-m", "linear", "--training", src], "takes no training data"),
        (["fill", src, "--extrapolate", "soon"], "--extrapolate expected"),
        (["fill", src, "-o", str(tmp_path / "dir") + "/"], "is a folder; give a file name"),
        (["fill", src, "-o", tmp_path / "dir"], "is a folder; give a file name"),
        (["fill", src, "-o", tmp_path / "nodir" / "o.c3d"], "does not exist"),
        (["fill", src, "-o", tmp_path / "o.xyz"], "unsupported file type"),
        (["fill", src, "-o", tmp_path / "o"], "no file type"),
        (["fill", folder], "fill them all with --out-dir"),
        (["fill", tmp_path / "absent.c3d"], "no such file"),
        (["fill", src, folder, "--out-dir", tmp_path / "o", "-m", "nope"], "unknown method"),
        (["fill", src, "--max-gap", "-1"], "max_gap expected"),
    ]
    for argv, needle in cases:
        assert main([str(a) for a in argv]) == 2, argv
        _one_error(capsys, needle)
    assert _snapshot(tmp_path) == before


# -- control characters, experiment names, symlink loops (#8) -------------------------------------
def test_control_characters_are_escaped_in_terminal_output(tmp_path, walk, capsys):
    evil = "\x1b]0;owned\x07\x1b[2J\u202eM"
    src = _recording(tmp_path / "e\x1b[31m.npz", walk,
                     labels=[evil, "M1\ntorchfill: fake", "M2\r\x1b[1A", "M3", "M4"],
                     units="mm\x1b[5m")
    out = tmp_path / "o\x1b[0m.npz"
    runs = [["info", str(src), "--all-markers"],
            ["fill", str(src), "-o", str(out), "-m", "linear", "--extrapolate", "0"],
            ["qc", str(src), str(out), "-o", str(tmp_path / "r.html")],
            ["fill", str(src), "-m", "no\x1b[2Jsuch"]]
    for argv in runs:
        main(argv)
        captured = capsys.readouterr()
        text = captured.out + captured.err
        for char in ("\x1b", "\x07", "\u202e", "\r"):
            assert char not in text, (argv, text)
        assert "\\x1b" in text, argv
        if argv[0] == "info":                           # a label cannot start a line of its own
            assert "M1\\ntorchfill: fake" in text
            assert not any(line.startswith("torchfill: fake") for line in text.splitlines())


def test_an_experiment_name_cannot_leave_the_results_folder(tmp_path, walk, capsys):
    data = tmp_path / "data"
    data.mkdir()
    _recording(data / "r.npz", walk)
    for name in ["../../../x", "a/b", "..", "x\x1b[2J"]:
        config = tmp_path / "exp" / "c.yaml"
        config.parent.mkdir(exist_ok=True)
        config.write_text(f"name: {name!r}\nrecordings: [r.npz]\nprotocol: multi_gap\n"
                          f"data_dir: {data}\nmethods: {{linear: {{}}}}\n".replace("'", '"'))
        before = _snapshot(tmp_path)
        assert main(["experiment", str(config)]) == 2
        _one_error(capsys, "name expected a plain folder name")
        assert _snapshot(tmp_path) == before


def test_an_out_dir_that_is_a_symlink_loop_is_one_line(tmp_path, walk, capsys):
    src = _recording(tmp_path / "a.npz", walk)
    os.symlink("loop", tmp_path / "loop")
    for out_dir in (tmp_path / "loop", tmp_path / "loop" / "sub"):
        assert main(["fill", str(src), "--out-dir", str(out_dir), "-m", "linear"]) == 2
        _one_error(capsys, "symbolic link loop")


def test_experiment_results_cannot_replace_a_recording(tmp_path, walk, capsys, monkeypatch):
    monkeypatch.delenv("TORCHFILL_DATA", raising=False)
    data = tmp_path / "data"
    data.mkdir()
    recording = data / "cases.csv"                      # a CSV recording named like a result
    torchfill.write(torchfill.MarkerSequence(points=walk(200, 4), labels=list("abcd")), recording)
    before = recording.read_bytes()
    config = tmp_path / "c.yaml"
    config.write_text(f"name: e\nrecordings: [cases.csv]\nprotocol: multi_gap\ndata_dir: {data}\n"
                      "grid: {n_markers: [1], gap_length: [10], max_gaps: [1]}\n"
                      "methods: {linear: {}}\n")
    assert main(["experiment", str(config), "--output", str(data)]) == 2
    _one_error(capsys, "would overwrite the recording")
    os.symlink("loop", tmp_path / "loop")
    assert main(["experiment", str(config), "--output", str(tmp_path / "loop" / "r")]) == 2
    _one_error(capsys, "symbolic link loop")
    assert recording.read_bytes() == before and sorted(os.listdir(data)) == ["cases.csv"]
