"""Progress of a fill: a bar with percent and time left on a terminal (tested through a pty),
nothing but the command's own lines in a pipe, only warnings and errors under -q (-qq: errors); the API's progress= argument."""
from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill import gaps, progress

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def gappy(gappy_sample) -> Path:
    """The embedded sample with 10 markers' gaps, as a fresh C3D."""
    return gappy_sample


def _env() -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1",
               TORCHFILL_PROGRESS_DELAY="0")          # show the bar at once (default: after 2 s)
    env.pop("TORCHFILL_DEBUG", None)
    return env


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "torchfill", *map(str, args)]


def _on_terminal(cmd: list[str]) -> tuple[int, str]:
    """Run ``cmd`` with stdin/stdout/stderr on a pty of 24 x 100 (a terminal); its output."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, env=_env(),
                            cwd=ROOT, close_fds=True)
    os.close(slave)
    out = b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:                      # EIO: the child closed the terminal
                break
            if not chunk:
                break
            out += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    return proc.wait(timeout=600), out.decode("utf-8", "replace")


def test_terminal_shows_percent_and_time_left(gappy, tmp_path):
    rc, out = _on_terminal(_cli("fill", gappy, "-o", tmp_path / "out.c3d", "-m", "svt"))
    assert rc == 0, out
    assert re.search(r"svt:\s+\d{1,3}%\|", out), out                 # percent
    assert re.search(r"\d\d:\d\d<\d\d:\d\d", out), out               # elapsed < time left
    assert "iter " in out
    assert "filled " in out                                          # the summary


def test_quiet_on_a_terminal_prints_nothing(gappy, tmp_path):
    rc, out = _on_terminal(_cli("fill", gappy, "-o", tmp_path / "out.c3d", "-m", "svt", "-q"))
    assert rc == 0 and out.strip() == "", out
    assert (tmp_path / "out.c3d").is_file()


def test_quiet_keeps_warnings_and_double_quiet_drops_them(gappy, tmp_path):
    cmd = _cli("fill", gappy, "-o", tmp_path / "out.c3d", "-m", "linear", "--max-gap", "20")
    quiet = subprocess.run(cmd + ["-q"], capture_output=True, text=True, env=_env(), cwd=ROOT)
    assert quiet.returncode == 0 and quiet.stdout == ""
    assert quiet.stderr.startswith("torchfill: warning:") and "left unfilled" in quiet.stderr
    silent = subprocess.run(cmd + ["-qq", "-o", str(tmp_path / "out2.c3d")], capture_output=True,
                            text=True, env=_env(), cwd=ROOT)
    assert silent.returncode == 0 and silent.stdout == "" and silent.stderr == ""


def test_quiet_still_prints_errors(tmp_path):
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"not a c3d file at all")
    rc, out = _on_terminal(_cli("fill", bad, "-o", tmp_path / "out.c3d", "-q"))
    assert rc == 2
    assert out.strip().startswith("torchfill: error:") and len(out.strip().splitlines()) == 1


def test_pipe_gets_no_bar(gappy, tmp_path):
    done = subprocess.run(_cli("fill", gappy, "-o", tmp_path / "out.c3d", "-m", "svt"),
                          capture_output=True, text=True, env=_env(), cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""                                  # no bar, no carriage returns
    assert "\r" not in done.stdout and "%|" not in done.stdout
    assert done.stdout.strip().splitlines()[-1].startswith("filled ")
    quiet = subprocess.run(_cli("fill", gappy, "-o", tmp_path / "q.c3d", "-m", "svt", "-q"),
                           capture_output=True, text=True, env=_env(), cwd=ROOT)
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""


def test_api_progress_true_off_a_terminal_is_one_summary_line(gappy, capsys):
    seq = torchfill.read(gappy)
    out = torchfill.fill(seq, "linear", progress=True)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("torchfill: linear filled "), err
    assert np.isfinite(out.points).all()
    torchfill.fill(seq, "linear")                                    # default: silent
    torchfill.fill(seq, "linear", progress=False)
    assert capsys.readouterr().err == ""


def test_api_progress_callable_gets_the_records(gappy):
    seq = torchfill.read(gappy)
    records = []
    torchfill.fill(seq, "svt", progress=records.append)
    assert records and [r["iter"] for r in records] == list(range(1, len(records) + 1))
    assert all(r["window"] == 1 and r["windows"] == 1 and r["max_iter"] == 1000 for r in records)
    assert all("delta" in r for r in records)


def test_api_progress_rejects_other_values(gappy):
    with pytest.raises(ValueError, match="progress expected"):
        torchfill.fill(torchfill.read(gappy), "linear", progress="yes")


class _Terminal:
    """A file that says it is a terminal and keeps what is written."""

    def __init__(self):
        self.text = ""

    def write(self, s):
        self.text += s

    def flush(self):
        pass

    def isatty(self):
        return True


def test_fraction_over_windows_and_stages():
    bar = progress.Bar(2, "tucker_tnn", file=_Terminal(), delay=0)
    seen = []
    for it in range(1, 101):                                  # window 1 of 2, max_iter 800
        bar.update({"window": 1, "windows": 2, "max_iter": 800, "iter": it})
        seen.append(bar.fraction())
    assert seen == sorted(seen) and seen[-1] == pytest.approx(0.45 * 100 / 800)
    bar.window_done(1, 100)                                   # window 2 now expects 125
    assert bar.fraction() == pytest.approx(0.45)
    bar.update({"window": 2, "windows": 2, "max_iter": 800, "iter": 50})
    assert bar.fraction() == pytest.approx(0.45 + 0.45 * 50 / 125)
    bar.post_step()
    assert bar.fraction() == pytest.approx(0.9)
    bar.close()
    assert "%|" in bar.file.text

    auto = progress.Bar(1, "auto", file=_Terminal(), delay=0)
    auto.update({"window": 1, "windows": 1, "iter": 1, "fit": 5.0, "fits": 10.0})
    assert auto.fraction() == pytest.approx(0.9 * 0.3)
    auto.update({"window": 1, "windows": 1, "iter": 1, "refit": 1.0, "refits": 2.0})
    assert auto.fraction() == pytest.approx(0.9 * (0.6 + 0.35 * 0.5))
    auto.close()


def test_a_long_step_still_moves_the_bar_every_second():
    """No record for 3 s inside auto's fits: the bar creeps on at least once a second, stays
    inside the stage under way, and the next record still moves it."""
    bar = progress.Bar(1, "auto", file=_Terminal(), delay=0)
    bar.update({"window": 1, "windows": 1, "iter": 1, "fit": 5.0, "fits": 10.0})
    start = bar.bar.n
    seen = []
    for _ in range(6):
        time.sleep(progress.TICK)
        seen.append(bar.bar.n)
    moves = [b > a for a, b in zip([start] + seen, seen)]
    assert sum(moves) >= 2 and seen == sorted(seen) and seen[-1] > start
    assert bar.bar.n < progress.UNITS * 0.9 * 0.6                 # not past the fits' stage
    bar.update({"window": 1, "windows": 1, "iter": 1, "refit": 1.0, "refits": 2.0})
    assert bar.bar.n == int(progress.UNITS * 0.9 * (0.6 + 0.35 * 0.5))
    bar.close()
