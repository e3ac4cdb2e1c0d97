"""TRC files (OpenSim / Motion Analysis track row column): tab-separated text.

Layout::

    PathFileType  4  (X/Y/Z)  name.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    100  100  238  41  mm  100  1  238
    Frame#  Time  LASI        RASI        ...
                  X1  Y1  Z1  X2  Y2  Z2  ...
    (an optional blank line)
    1  0.000  x  y  z  x  y  z  ...

Header rows are parsed positionally (the non-empty cells in order), because some files double the
tabs in those rows (``osim_rajagopal_motion_capture_walk.trc``), which misaligns a cell-by-cell
key/value parse. A missing sample is an empty cell, a ``NaN`` cell, a row cut short, or an exact
(0, 0, 0) (a dead marker, as in ``osim_hamner_subject02_running.trc``; ``zeros_missing=False``
keeps such samples).

Writing a sequence read from a TRC keeps the source's header lines and every untouched cell
byte-for-byte and changes only the cells of filled samples, formatted with as many decimals as
the file's own cells. Without a TRC source, a fresh file is written.

Every row torchfill writes has all its cells: a missing sample is three empty cells, and a row
whose last cell is empty ends with one more tab, as OpenSim's own writer ends every row.
OpenSim 4.6's ``TRCFileAdapter`` drops a trailing empty token and then rejects the file
("Unexpected number of columns"); Pose2Sim reads the rows with ``pandas.read_csv(sep="\t",
skiprows=4)`` under the ``X1 Y1 Z1 ...`` line, which therefore ends with a tab too (a row one
cell longer than that line would turn the frame column into pandas' index), and drops the
``Unnamed`` column the trailing tab makes. A write-back pads the source's short rows the same way
(their cells are kept).

Filled samples are recorded beside the file, in ``NAME.trc.filled``: a small tab-separated table
of runs (marker number M as in ``XM``, its label, first and last data row, 1-based, inclusive)
under a comment line that carries the SHA-256 of the TRC it describes. Line 1 stays the plain
``PathFileType`` line every reader expects. The reader returns the runs as ``meta["filled"]``, so
that a second fill keeps those samples but does not fit to them (:func:`torchfill.fill`); a record
that does not match its TRC (the TRC was changed since) is ignored with a warning. Files written
by earlier versions carry the runs in line 1 as one more cell ``torchfill-filled=M:A-B,...``;
they are read the same way, and a write-back drops that cell.

For OpenSim, ``write(..., axes="zup-to-yup", units="m")`` turns a lab's Z-up millimetres into
OpenSim's Y-up metres (:func:`torchfill.sequence.parse_axes`, :func:`~torchfill.sequence.unit_power`):
every written sample is turned and scaled, nothing else (frames, times, rate, labels, the filled
record). Numbers keep the precision of the source -- a TRC's decimals, a C3D's float32 values as
the shortest text that reads back as the same float32, an integer C3D's scale -- and the unit
change moves the decimal point of that text, so no digit is invented or lost. Without a source
precision (arrays), observed values are written exactly and filled values with 6 significant
digits, as OpenSim's own writer does.

References
----------
.. [1] OpenSim documentation, *Marker (.trc) Files*,
   https://opensimconfluence.atlassian.net/wiki/spaces/OpenSim/pages/53089972
"""
from __future__ import annotations

import hashlib
import io
import math
import re
import warnings
from decimal import Decimal
from pathlib import Path

import numpy as np

from . import FileFormatError
from ._common import (atomic_write, check_writable, filled_samples, storable_labels,
                      unwritten_edits)
from ..sequence import MarkerSequence, parse_axes, unit_power

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def _fail(path, problem: str):
    raise FileFormatError(f"{path}: {problem}")


def _cells(line: str) -> list[str]:
    return line.rstrip("\r\n").split("\t")


_LINE = re.compile(r"[^\r\n]*(?:\r\n|\n|\r|$)")


def _split_lines(text: str) -> list[str]:
    """Lines with their line endings kept (so a write-back can reproduce them). Only CR, LF and
    CRLF end a line: ``str.splitlines`` would also break at control characters such as \\x1e
    inside a cell."""
    lines = _LINE.findall(text)
    return [line for line in lines if line]


class _Parsed:
    """A TRC file split into header lines and data lines, plus what the header says."""

    def __init__(self, path: Path, text: str, encoding: str = "utf-8"):
        self.path = path
        self.encoding = encoding
        self.lines = _split_lines(text)
        if not text.strip():
            _fail(path, "empty file")
        if len(self.lines) < 5 or not self.lines[0].startswith("PathFileType"):
            _fail(path, "not a TRC file (first line must start with 'PathFileType')")
        keys = [c.strip() for c in _cells(self.lines[1]) if c.strip()]
        values = [c.strip() for c in _cells(self.lines[2]) if c.strip()]
        self.header = dict(zip(keys, values))
        names = _cells(self.lines[3])
        if len(names) < 2 or names[0].strip() != "Frame#":
            _fail(path, "not a TRC file (line 4 must start with 'Frame#')")
        self.labels = [c.strip() for c in names[2:] if c.strip()]
        if not self.labels:
            _fail(path, "no markers (line 4 names none)")
        self.first_data = 5
        while self.first_data < len(self.lines) and not self.lines[self.first_data].strip():
            self.first_data += 1
        self.data_lines = [i for i in range(self.first_data, len(self.lines))
                           if self.lines[i].strip()]

    def number(self, key: str, default=None):
        value = self.header.get(key)
        if value is None:
            return default
        try:
            return float(value)
        except ValueError:
            _fail(self.path, f"header {key} is {value!r}, not a number")

    def table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frame numbers, times, points (T, J, 3)) from the data lines; NaN for missing cells."""
        J = len(self.labels)
        T = len(self.data_lines)
        if T == 0:
            _fail(self.path, "no data rows")
        fast = self._fast_table(J)
        if fast is not None:
            return fast
        frames = np.empty(T)
        times = np.empty(T)
        values = np.full((T, 3 * J), np.nan)
        for r, i in enumerate(self.data_lines):
            cells = _cells(self.lines[i])
            if len(cells) > 2 + 3 * J and any(c.strip() for c in cells[2 + 3 * J:]):
                _fail(self.path, f"line {i + 1}: {len(cells) - 2} values for {J} markers")
            try:
                frames[r] = _cell(cells[0])
                times[r] = _cell(cells[1]) if len(cells) > 1 else math.nan
                row = [_cell(c) for c in cells[2:2 + 3 * J]]
            except ValueError as err:
                _fail(self.path, f"line {i + 1}: {err}")
            values[r, :len(row)] = row
        return frames, times, values.reshape(T, J, 3)

    def _fast_table(self, J: int):
        """The common case (every row complete, no empty cells) with NumPy's C parser; None if
        any row is irregular (then the cell-by-cell parse finds and names the problem)."""
        text = "\n".join(self.lines[i].rstrip("\t\r\n") for i in self.data_lines)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                table = np.loadtxt(io.StringIO(text), delimiter="\t", ndmin=2)
        except ValueError:
            return None
        if table.shape != (len(self.data_lines), 2 + 3 * J) or np.isinf(table).any():
            return None
        return table[:, 0], table[:, 1], table[:, 2:].reshape(-1, J, 3).copy()


def _cell(text: str) -> float:
    text = text.strip()
    if not text or text.lower() in ("nan", "-nan", "+nan"):
        return math.nan
    if not _NUMBER.match(text):
        if text.lower().lstrip("+-") in ("inf", "infinity"):
            raise ValueError(f"infinite value {text!r} (missing samples must be empty or NaN)")
        raise ValueError(f"{text!r} is not a number")
    value = float(text)
    if math.isinf(value):
        raise ValueError(f"{text!r} overflows a 64-bit float")
    return value


def _load(path: Path) -> _Parsed:
    if not path.is_file():
        _fail(path, "no such file")
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise FileFormatError(f"{path}: cannot read ({err.strerror or err})") from None
    if b"\x00" in raw[:4096]:
        _fail(path, "not a TRC file (binary content)")
    try:
        parsed = _Parsed(path, raw.decode("utf-8"), "utf-8")
    except UnicodeDecodeError:                 # older files: Latin-1 (every byte decodes)
        parsed = _Parsed(path, raw.decode("latin-1"), "latin-1")
    parsed.digest = hashlib.sha256(raw).hexdigest()
    return parsed


def read(path, *, zeros_missing: bool = True, markers_only: bool = True) -> MarkerSequence:
    """Read a TRC file into a :class:`MarkerSequence`.

    Parameters
    ----------
    path : str or Path
    zeros_missing : bool, default True
        Treat samples stored as exactly (0, 0, 0) as missing.
    markers_only : bool
        Ignored (a TRC holds markers only); accepted so all readers take the same arguments.

    Returns
    -------
    MarkerSequence
        ``rate`` from DataRate, ``units`` from Units; ``meta`` holds ``frame_numbers``, ``time``
        and ``first_frame``.
    """
    path = Path(path)
    parsed = _load(path)
    frames, times, points = parsed.table()
    J = len(parsed.labels)
    declared = parsed.number("NumMarkers")
    if declared is not None and declared != J:
        warnings.warn(f"{path.name}: header says {declared:g} markers, labels name {J}",
                      stacklevel=2)
    if zeros_missing:
        points[(points == 0).all(axis=2)] = np.nan
    rate = parsed.number("DataRate") or parsed.number("CameraRate")
    if rate is not None and not (math.isfinite(rate) and rate >= 0):
        _fail(path, f"header DataRate/CameraRate is {rate}, expected a positive number")
    if not rate and len(times) > 1 and np.isfinite(times[:2]).all() and times[1] > times[0]:
        rate = 1.0 / (times[1] - times[0])
    numbers = np.where(np.isfinite(frames), frames, 0)
    numbers = np.clip(numbers, -2**62, 2**62).astype(np.int64)
    meta = {"frame_numbers": numbers, "time": times}
    filled = _filled_runs(parsed, len(frames), J)
    if filled is None:
        filled = _side_record(parsed, len(frames), J)
    if filled is not None:
        filled &= np.isfinite(points).all(axis=2)
        if filled.any():
            meta["filled"] = filled
    first = int(numbers[0]) if np.isfinite(frames[0]) and abs(frames[0]) < 2**62 else 1
    return MarkerSequence(points=points, labels=parsed.labels, rate=float(rate or 100.0),
                          units=parsed.header.get("Units", "mm"), source=path, meta=meta,
                          first_frame=first)


_FILLED_KEY = "torchfill-filled="


def _filled_runs(parsed: "_Parsed", T: int, J: int) -> np.ndarray | None:
    """``(T, J)`` filled samples named in the first line's ``torchfill-filled=`` cell (None if
    absent; a warning and None if it does not fit this file)."""
    cells = [c.strip() for c in _cells(parsed.lines[0]) if c.strip().startswith(_FILLED_KEY)]
    if not cells:
        return None
    filled = np.zeros((T, J), dtype=bool)
    try:
        for run in filter(None, cells[-1][len(_FILLED_KEY):].split(",")):
            m, _, rows = run.partition(":")
            a, _, b = rows.partition("-")
            m, a, b = int(m), int(a), int(b or a)
            if not (1 <= m <= J and 1 <= a <= b <= T):
                raise ValueError(run)
            filled[a - 1:b, m - 1] = True
    except ValueError as err:
        warnings.warn(f"{parsed.path.name}: the first line's {_FILLED_KEY[:-1]} record does not fit "
                      f"this file ({_first(err)}); filled samples are not marked", stacklevel=3)
        return None
    return filled


#: The suffix of the filled-samples record beside a TRC (``walk.trc`` -> ``walk.trc.filled``).
SIDE = ".filled"


def side_path(path) -> Path:
    """Where the filled-samples record of the TRC ``path`` lies."""
    path = Path(path)
    return path.with_name(path.name + SIDE)


def _side_record(parsed: "_Parsed", T: int, J: int) -> np.ndarray | None:
    """``(T, J)`` filled samples from the record beside the file (None if there is none; a
    warning and None if it does not describe this file)."""
    side = side_path(parsed.path)
    if not side.is_file():
        return None
    problem, filled = None, np.zeros((T, J), dtype=bool)
    try:
        lines = side.read_text(encoding="utf-8").splitlines()
        if not lines or f"sha256 {parsed.digest}" not in lines[0]:
            problem = f"{parsed.path.name} changed since it was written"
        for line in lines[2:] if problem is None else []:
            m, _, a, b = line.split("\t")
            m, a, b = int(m), int(a), int(b)
            if not (1 <= m <= J and 1 <= a <= b <= T):
                raise ValueError(line)
            filled[a - 1:b, m - 1] = True
    except (OSError, UnicodeDecodeError, ValueError) as err:
        problem = f"unreadable ({_first(err)})"
    if problem:
        warnings.warn(f"{side.name}: {problem}; filled samples are not marked", stacklevel=3)
        return None
    return filled


def _side_text(filled: np.ndarray, labels: list[str], name: str, digest: str) -> str:
    """The record beside a TRC: its runs of filled samples, one per line."""
    rows = [f"# torchfill: samples of {name} a fill made (data rows, 1-based, inclusive); "
            f"sha256 {digest}", "marker\tlabel\tfirst_row\tlast_row"]
    for j in range(filled.shape[1]):
        col = np.concatenate([[False], filled[:, j], [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(col))
        rows += [f"{j + 1}\t{labels[j]}\t{a + 1}\t{b}" for a, b in zip(edges[::2], edges[1::2])]
    return "\n".join(rows) + "\n"


def _write_side(path: Path, text: str, filled: np.ndarray | None, labels: list[str]) -> None:
    """Write the TRC ``text`` to ``path`` and, when samples are filled, its record beside it."""
    data = text.encode("utf-8") if isinstance(text, str) else text
    if filled is not None and filled.any():
        side = _side_text(filled, labels, path.name, hashlib.sha256(data).hexdigest())
        atomic_write(side_path(path), lambda handle: handle.write(side.encode("utf-8")))
    atomic_write(path, lambda handle: handle.write(data))


def _first(err: Exception) -> str:
    text = str(err).strip()
    return text[:40] if text else type(err).__name__


def _first_line(line: str) -> str:
    """Line 1 without an earlier version's ``torchfill-filled=`` cell."""
    body = line.rstrip("\r\n")
    ending = line[len(body):]
    old = body.split("\t")
    cells = [c for c in old if not c.strip().startswith(_FILLED_KEY)]
    if len(cells) == len(old):
        return line
    while len(cells) > 1 and not cells[-1].strip():
        cells.pop()
    return "\t".join(cells) + ending


def _full_row(cells: list[str], n: int) -> list[str]:
    """A data row's cells, padded to ``n`` (frame, time and 3 per marker) and given one more
    empty cell (a trailing tab) when its last cell is empty: OpenSim drops a trailing empty token."""
    if len(cells) < n or (len(cells) == n and not cells[-1].strip()):
        cells = cells + [""] * (n - len(cells)) + [""]
    return cells


def write(seq: MarkerSequence, path, *, decimals: int | None = None, axes=None,
          units: str | None = None) -> None:
    """Write ``seq`` as a TRC file, atomically, with the record of its filled samples beside it.

    When ``seq.source`` is a TRC file with the same frames and markers and no axes or units
    change is asked, its header lines and all untouched cells are kept; only the cells of filled
    samples (``seq.meta["filled"]``, else the samples missing in the source and finite in
    ``seq``) change, written with the file's own number of decimals (or ``decimals``), and short
    rows are padded (see the module notes). Otherwise a fresh TRC is written (frame numbers from
    ``seq.first_frame``, missing samples as empty cells, numbers with the source's precision).

    Parameters
    ----------
    decimals : int, optional
        Decimals of every written coordinate (default: the source's precision).
    axes : str, optional
        Turn every sample: ``"zup-to-yup"`` (a lab's Z-up to OpenSim's Y-up), ``"yup-to-zup"`` or
        a signed permutation such as ``"x,z,-y"``.
    units : {"m", "cm", "mm"}, optional
        Scale every sample into these units (the header's Units says them).
    """
    path = Path(path)
    check_writable(seq, path)
    turn = _Turn(seq, axes, units)
    source = Path(seq.source) if seq.source is not None else None
    parsed = None
    if source is not None and source.suffix.lower() == ".trc" and source.is_file():
        parsed = _load(source)
        if (turn.identity and len(parsed.data_lines) == seq.n_frames
                and parsed.labels == seq.labels):
            return _write_back(seq, path, parsed, decimals)
    filled = seq.meta.get("filled")
    filled = (np.asarray(filled, dtype=bool) & np.isfinite(seq.points).all(axis=2)
              if filled is not None and np.shape(filled) == seq.points.shape[:2] else None)
    numbers = _Numbers(seq, parsed, decimals)
    labels = storable_labels(seq.labels, _trc_label, _trc_labels_back, path)
    _write_side(path, _fresh_text(seq, path, labels, turn, numbers, filled), filled, labels)


class _Turn:
    """The axes and units change of a write: new coordinate ``i`` is ``signs[i] *
    old[order[i]] * 10**power``, applied to the text of each number (exact)."""

    def __init__(self, seq: MarkerSequence, axes, units: str | None):
        self.order, self.signs = parse_axes(axes) if axes is not None else ((0, 1, 2), (1, 1, 1))
        try:
            self.power = 0 if units is None else unit_power(seq.units, units)
        except ValueError as err:
            raise ValueError(f"{err} (the recording's units are {seq.units!r})") from None
        self.units = seq.units if units is None else units
        self.identity = self.order == (0, 1, 2) and self.signs == (1, 1, 1) and self.power == 0

    def apply(self, texts: list[str]) -> list[str]:
        """One sample's three number texts (empty: missing), turned and scaled."""
        return [_signed(_shifted(texts[o], self.power), s) for o, s in zip(self.order, self.signs)]


def _shifted(text: str, power: int) -> str:
    """``text`` times ``10**power``, by moving its decimal point."""
    if not power or not text:
        return text
    return format(Decimal(text).scaleb(power), "f")


def _signed(text: str, sign: int) -> str:
    if sign > 0 or not text or float(text) == 0:
        return text
    return text[1:] if text.startswith("-") else "-" + text.lstrip("+")


class _Numbers:
    """How a fresh TRC writes numbers: the source's precision (see the module notes)."""

    def __init__(self, seq: MarkerSequence, parsed: _Parsed | None, decimals: int | None):
        c3d = seq.meta.get("c3d") or {}
        self.decimals = decimals
        self.digits = None                    # significant digits of filled values, else None
        self.float32 = False
        if decimals is not None:
            return
        if parsed is not None:
            self.decimals = _decimals([c for i in parsed.data_lines[:50]
                                       for c in _cells(parsed.lines[i])[2:]])
        elif c3d.get("format") == "float32":
            self.float32 = True
        elif c3d.get("format") == "int16" and c3d.get("scale"):
            self.decimals = max(0, math.floor(-math.log10(abs(float(c3d["scale"]))))) + 1
        else:
            self.digits = 6

    def text(self, value: float, filled: bool) -> str:
        if self.decimals is not None:
            return f"{value:.{self.decimals}f}"
        if self.float32:
            return np.format_float_positional(np.float32(value), unique=True, trim="-")
        if filled:
            return np.format_float_positional(value, precision=self.digits, unique=True,
                                              fractional=False, trim="-")
        return np.format_float_positional(value, unique=True, trim="-")


def _write_back(seq: MarkerSequence, path: Path, parsed: _Parsed, decimals: int | None) -> None:
    _, _, cells_in = parsed.table()
    src = cells_in.copy()
    src[(src == 0).all(axis=2)] = np.nan
    filled = filled_samples(seq, np.isfinite(src).all(axis=2), path)
    edits = unwritten_edits(seq, src, filled)
    if edits:
        warnings.warn(f"{path.name}: {edits} sample(s) differ from {parsed.path.name} but were "
                      "not filled; only filled samples are written back", stacklevel=4)
    # a partly missing sample keeps its observed cells byte for byte; a whole sample marked
    # filled although valid in the source (fill(mask=...)) or a (0, 0, 0) dead marker is rewritten
    partial = ~np.isfinite(cells_in).all(axis=2) & np.isfinite(cells_in).any(axis=2)
    rewrite = ~(partial[..., None] & np.isfinite(cells_in))
    J = seq.n_markers
    n = 2 + 3 * J
    lines = list(parsed.lines)
    lines[0] = _first_line(lines[0])
    rows = []
    for t, i in enumerate(parsed.data_lines):
        cells = lines[i].rstrip("\r\n").split("\t")
        if filled[t].any():
            places = decimals if decimals is not None else _decimals(cells[2:])
            cells += [""] * (n - len(cells))
            for j in np.flatnonzero(filled[t]):
                cells[2 + 3 * j:5 + 3 * j] = _sample_cells(cells[2 + 3 * j:5 + 3 * j],
                                                           seq.points[t, j], rewrite[t, j], places)
        rows.append(cells)
    # one row that needs a trailing tab (OpenSim) gives every row and the X1 Y1 Z1 line one, so
    # that pandas (Pose2Sim) sees the same number of cells everywhere
    trailing = any(len(_full_row(cells, n)) > n for cells in rows)
    for t, (i, cells) in enumerate(zip(parsed.data_lines, rows)):
        full = _full_row(cells, n)
        if trailing and len(full) == n:
            full = full + [""]
        if full != lines[i].rstrip("\r\n").split("\t"):
            lines[i] = "\t".join(full) + lines[i][len(lines[i].rstrip("\r\n")):]
    axes = lines[4].rstrip("\r\n")
    if trailing and len(axes.split("\t")) == n:
        lines[4] = axes + "\t" + lines[4][len(axes):]
    _write_side(path, "".join(lines).encode(parsed.encoding), filled, seq.labels)


def _sample_cells(cells: list[str], xyz: np.ndarray, rewrite: np.ndarray, places: int) -> list[str]:
    """The three cells of a filled sample: rewritten coordinates formatted with ``places``
    decimals, the others kept. A sample that would read as (0, 0, 0), the dead-marker mark, gets
    its last rewritten coordinate moved by one unit of the last decimal (towards its sign)."""
    out = [f"{v:.{places}f}" if r else c for c, v, r in zip(cells, xyz.tolist(), rewrite)]
    if all(_cell(c) == 0 for c in out):
        k = int(np.flatnonzero(rewrite)[-1])
        out[k] = f"{math.copysign(10.0 ** -places, xyz[k] or 1.0):.{places}f}"
    return out


def _decimals(cells: list[str]) -> int:
    """Decimals used by a row's numeric cells (the most seen), 6 if none."""
    places = [len(c.strip().split(".")[1]) for c in cells
              if "." in c and "e" not in c.lower() and c.strip()]
    return max(places) if places else 6


def _trc_label(label: str, j: int) -> str:
    """A label as a TRC header cell: no tabs or line breaks, no outer spaces, never empty."""
    return re.sub(r"[\t\r\n]+", " ", label).strip() or f"M{j + 1}"


def _trc_labels_back(stored: list[str]) -> list[str]:
    return [c.strip() for c in stored if c.strip()]


def _fresh_text(seq: MarkerSequence, path: Path, labels: list[str], turn: _Turn,
                numbers: _Numbers, filled: np.ndarray | None) -> str:
    T, J = seq.n_frames, seq.n_markers
    first = int(seq.first_frame)
    rate = float(seq.rate)
    name = re.sub(r"[\t\r\n]+", " ", path.name)
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
        "OrigDataStartFrame\tOrigNumFrames",
        f"{rate:.12g}\t{rate:.12g}\t{T}\t{J}\t{_trc_units(turn.units)}\t{rate:.12g}\t{first}\t{T}",
        "Frame#\tTime\t" + "".join(f"{label}\t\t\t" for label in labels),
        "\t\t" + "".join(f"X{j + 1}\tY{j + 1}\tZ{j + 1}\t" for j in range(J)),
        "",
    ]
    finite = np.isfinite(seq.points).all(axis=2)
    made = filled if filled is not None else np.zeros((T, J), dtype=bool)
    for t in range(T):
        cells = []
        for j, xyz in enumerate(seq.points[t].tolist()):
            texts = ([numbers.text(v, made[t, j]) for v in xyz] if finite[t, j] else
                     ["" if math.isnan(v) else numbers.text(v, False) for v in xyz])
            cells += turn.apply(texts)
        lines.append(f"{first + t}\t{t / rate:.6f}\t" + "\t".join(cells) + "\t")
    return "\n".join(lines) + "\n"


def _trc_units(units: str) -> str:
    """Units as one header cell (no tabs, line breaks or spaces; never empty)."""
    return re.sub(r"\s+", "", str(units)) or "mm"


__all__ = ["read", "write"]
