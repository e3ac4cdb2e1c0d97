"""What the command line owns of the process: threads, signals, escaped output, one-line errors."""
from __future__ import annotations

import os
import re
import signal
import sys


EXIT_ERROR = 2


def _set_threads(n: int | None) -> None:
    """torch's threads for this run: ``--threads``, else ``OMP_NUM_THREADS``, else the cores the
    machine leaves idle (at least 1). Threads that wait for busy cores are far slower than one:
    a tucker_tnn iteration on 3000 x 41 frames took 84-93 ms with 1 thread and 685-1427 ms with 2
    on a loaded 2-core machine (docs/speed.md)."""
    if n is None:
        if os.environ.get("OMP_NUM_THREADS"):
            return
        cores = os.cpu_count() or 1
        n = max(1, min(cores, int(cores - os.getloadavg()[0] + 0.5)))
    elif n < 1:
        raise ValueError(f"--threads expected >= 1, found {n}")
    os.environ["OMP_NUM_THREADS"] = str(n)       # read when torch is imported (lazily, later)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)


def _install_signal_handlers() -> None:
    """SIGTERM ends the run like Ctrl-C (clean-up runs: no temporary file is left behind)."""
    def on_term(signum, frame):
        raise SystemExit(128 + signum)
    try:
        signal.signal(signal.SIGTERM, on_term)
    except ValueError:                     # not the main thread
        pass


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


#: characters that can move the cursor, retitle, clear or recolour a terminal, or reorder text:
#: C0 and C1 controls but tab and newline, DEL, bidirectional overrides and isolates
_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def escape(text: str) -> str:
    """``text`` with terminal control characters shown as escapes (``\\x1b``): labels, units and
    file names come from files and must not drive the terminal that prints them."""
    return _CONTROL.sub(lambda m: (f"\\x{ord(m[0]):02x}" if ord(m[0]) < 256
                                   else f"\\u{ord(m[0]):04x}"), text)


def _shown(text: str) -> str:
    """One field of a table as printed: control characters and line breaks escaped."""
    return escape(str(text)).replace("\n", "\\n").replace("\t", "\\t")


class _Escaping:
    """A text stream that escapes control characters in what it is given (:func:`escape`); a
    carriage return at the start or end of one write stays (progress lines rewrite themselves)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        body = text.strip("\r")
        if body != text:
            head = text[:len(text) - len(text.lstrip("\r"))]
            tail = text[len(text.rstrip("\r")):] if body else ""
            text = head + escape(body) + tail
        else:
            text = escape(text)
        return self._stream.write(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__
