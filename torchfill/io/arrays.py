"""Plain arrays: ``.npy``, ``.npz`` and ``.csv``.

* ``.npy``: one float array of shape ``(T, J, 3)`` or ``(T, 3J)`` (columns x1 y1 z1 x2 ...).
* ``.npz``: key ``points`` (as for .npy), optional ``labels`` (J strings), ``rate`` (Hz),
  ``units`` (a string), ``first_frame`` (an integer) and ``filled`` ((T, J) bool: the samples a
  fill made, ``meta["filled"]``).
* ``.csv``: numbers, comma- (or semicolon- or tab-) separated, columns x1,y1,z1,x2,...; optional
  leading comment lines ``# rate=50; units=mm; first_frame=1`` (torchfill writes one: ``#``
  lines are skipped by ``numpy.loadtxt``/``genfromtxt`` and by ``pandas.read_csv(...,
  comment="#")``), then an optional row of column names (``LASI_X,LASI_Y,LASI_Z,...``: the marker
  label is the name without its trailing axis letter; or one name per marker followed by two
  empty cells). A last column named ``filled`` lists, per row, the 1-based numbers of the
  markers a fill made in that frame, separated by spaces (``meta["filled"]``).

Missing samples are ``NaN`` (or empty CSV cells; torchfill writes empty cells in a CSV and NaN in
.npy/.npz); a sample with any missing coordinate is missing. ``+-inf`` is an error. Rate and units
that the file does not hold come from the ``rate=`` and ``units=`` arguments (defaults 100 Hz,
mm); .npy holds the points only.

Sizes a file claims are checked before anything is allocated: an array's header against the bytes
present, and an .npz member's inflated size against ``MAX_INFLATION`` x its compressed size.
"""
from __future__ import annotations

import csv
import io
import math
import re
import warnings
import zipfile
from pathlib import Path

import numpy as np

from . import FileFormatError
from ._common import atomic_write, check_writable, default_labels, reject_inf, storable_labels
from ..sequence import MarkerSequence

#: An .npz member may inflate to at most this many times its compressed size (and
#: ``MIN_INFLATED`` bytes in any case): deflate stores marker data at 1-3x, a recording that is
#: almost all NaN at up to ~1000x, a zip bomb at its maximum (~1000x). Beyond it the file is
#: refused before anything is inflated.
MAX_INFLATION = 100
MIN_INFLATED = 64 << 20

_AXIS = re.compile(r"^(?P<name>.*?)[\s_.:\-]*(?P<axis>[xyzXYZ])(?P<num>\d*)$")


def _fail(path, problem: str):
    raise FileFormatError(f"{path}: {problem}")


def _as_points(array: np.ndarray, path: Path) -> np.ndarray:
    """``(T, J, 3)`` float64 from a ``(T, J, 3)`` or ``(T, 3J)`` numeric array; ``(T, J, 2)``
    (image keypoints) is kept as it is."""
    if array.dtype.kind not in "fiub":
        _fail(path, f"expected a numeric array, found dtype {array.dtype}")
    if array.ndim == 2 and array.shape[1] % 3 == 0 and array.shape[1] > 0:
        array = array.reshape(array.shape[0], array.shape[1] // 3, 3)   # x1 y1 z1 x2 ... (C order)
    if array.ndim != 3 or array.shape[2] not in (2, 3) or array.shape[1] == 0:
        _fail(path, f"wrong array shape {array.shape}: expected (frames, markers, 3), "
                    f"(frames, 3 x markers) or (frames, keypoints, 2)")
    if array.shape[0] == 0:
        _fail(path, "no frames")
    points = np.array(array, dtype=np.float64)
    reject_inf(points, path)
    return points


def _nan_rows(points: np.ndarray) -> np.ndarray:
    """A sample with any NaN coordinate is missing in all three."""
    points[~np.isfinite(points).all(axis=2)] = np.nan
    return points


def read(path, *, rate: float | None = None, units: str | None = None,
         markers_only: bool = True) -> MarkerSequence:
    """Read ``.npy``, ``.npz`` or ``.csv`` into a :class:`MarkerSequence` (``markers_only`` is
    accepted for a uniform signature and ignored)."""
    path = Path(path)
    if not path.is_file():
        _fail(path, "no such file")
    if path.stat().st_size == 0:
        _fail(path, "empty file")
    suffix = path.suffix.lower()
    extra: dict = {}
    if suffix == ".csv":
        points, labels, meta_rate, meta_units = _read_csv(path, extra)
    else:
        points, labels, meta_rate, meta_units = _read_numpy(path, suffix, extra)
    points = _nan_rows(points)
    J = points.shape[1]
    meta = {}
    filled = extra.get("filled")
    if filled is not None:
        if filled.shape != points.shape[:2]:
            _fail(path, f"'filled' has shape {filled.shape}, expected {points.shape[:2]} "
                        "(frames x markers)")
        filled = filled & np.isfinite(points).all(axis=2)
        if filled.any():
            meta["filled"] = filled
    if suffix == ".csv" and labels is None:
        meta["csv_header"] = False           # a write-back to CSV keeps it headerless
        if rate is None or units is None:
            warnings.warn(f"{path.name}: no header row; labels M1..M{J}"
                          + (", 100 Hz" if rate is None else "")
                          + (", mm" if units is None else "") + " assumed", stacklevel=3)
    labels = labels or default_labels(J)
    if len(labels) != J:
        _fail(path, f"{len(labels)} labels for {J} markers")
    return MarkerSequence(points=points, labels=labels,
                          rate=float(rate or meta_rate or 100.0),
                          units=str(units or meta_units or "mm"), source=path, meta=meta,
                          first_frame=int(extra.get("first_frame", 0)))


def _read_numpy(path: Path, suffix: str, extra: dict):
    try:
        if suffix == ".npy":
            with open(path, "rb") as handle:
                return _as_points(_npy_array(handle, path.stat().st_size, path), path), \
                    None, None, None
        with zipfile.ZipFile(path) as archive:
            members = {name[:-4]: name for name in archive.namelist() if name.endswith(".npy")}
            if "points" not in members:
                _fail(path, f"no 'points' array (found {', '.join(members) or 'nothing'})")
            arrays = {}
            for key in ("points", "labels", "rate", "units", "first_frame", "filled"):
                if key in members:
                    info = archive.getinfo(members[key])
                    _check_inflation(info, path)
                    with archive.open(info) as handle:
                        arrays[key] = _npy_array(handle, info.file_size, path)
    except FileFormatError:
        raise
    except Exception as err:   # noqa: BLE001 - NumPy's header parser and zipfile raise many kinds
        _fail(path, f"not a valid {suffix} file ({type(err).__name__}: {_first_line(err)})")
    points = _as_points(arrays["points"], path)
    try:
        labels = [str(s) for s in arrays["labels"].reshape(-1)] if "labels" in arrays else None
        rate = float(arrays["rate"]) if "rate" in arrays else None
        units = str(arrays["units"]) if "units" in arrays else None
    except (ValueError, TypeError) as err:
        _fail(path, f"bad .npz content ({_first_line(err)})")
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        _fail(path, f"rate must be a positive number, found {rate}")
    if "first_frame" in arrays:
        first = arrays["first_frame"].reshape(-1)
        if first.size != 1 or first.dtype.kind not in "iu":
            _fail(path, f"first_frame must be one integer, found {first.dtype} x {first.size}")
        extra["first_frame"] = int(first[0])
    if "filled" in arrays:
        if arrays["filled"].dtype != np.bool_:
            _fail(path, f"'filled' must be a bool array, found {arrays['filled'].dtype}")
        extra["filled"] = np.asarray(arrays["filled"])
    return points, labels, rate, units


def _check_inflation(info: zipfile.ZipInfo, path: Path) -> None:
    """Refuse an .npz member that claims to inflate beyond ``MAX_INFLATION`` x its stored size
    (a zip bomb), before any of it is inflated."""
    limit = max(MIN_INFLATED, MAX_INFLATION * info.compress_size)
    if info.file_size > limit:
        _fail(path, f"member {info.filename} inflates {info.file_size} bytes from "
                    f"{info.compress_size} (more than {MAX_INFLATION}x); refused as a "
                    f"decompression bomb")


def _npy_array(handle, size: int, path: Path) -> np.ndarray:
    """One ``.npy`` array from ``handle`` (``size`` bytes in all), its header checked against
    ``size`` first: a header claiming more data than the file holds is an error, not a huge
    allocation."""
    fmt = np.lib.format
    version = fmt.read_magic(handle)
    read_header = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(
        version)
    if read_header is None:
        raise ValueError(f"unsupported .npy version {version}")
    shape, fortran, dtype = read_header(handle)
    if dtype.hasobject:
        raise ValueError("object arrays are not read (pickles are refused)")
    need = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if need > size:
        raise ValueError(f"header claims shape {shape} ({need} bytes) but only {size} bytes exist")
    count = int(np.prod(shape, dtype=np.int64))
    data = handle.read(count * dtype.itemsize)
    if len(data) != count * dtype.itemsize:
        raise EOFError(f"array data cut short ({len(data)} of {count * dtype.itemsize} bytes)")
    array = np.frombuffer(data, dtype=dtype, count=count)
    return array.reshape(shape[::-1]).T if fortran else array.reshape(shape)


def _first_line(err: Exception) -> str:
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


def _read_csv(path: Path, extra: dict):
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        _fail(path, "not a text CSV file (binary content)")
    text, settings = _csv_comments(text, path)
    extra.update((k, v) for k, v in settings.items() if k == "first_frame")
    try:
        rows = [r for r in csv.reader(io.StringIO(text), delimiter=_delimiter(text))
                if len(r) > 1 or (r and r[0].strip())]   # blank lines go; ",,," is a frame
    except csv.Error as err:
        _fail(path, f"not a readable CSV file ({_first_line(err)})")
    if not rows:
        _fail(path, "empty file")
    labels = None
    filled_rows = None
    if not all(_is_number(c) for c in rows[0]):
        header, rows = rows[0], rows[1:]
        while len(header) > 1 and not header[-1].strip() and len(header) % 3 == 1:
            header = header[:-1]                 # a trailing separator
        if len(header) % 3 == 1 and header[-1].strip().lower() == "filled":
            header = header[:-1]
            filled_rows = [r[len(header)] if len(r) > len(header) else "" for r in rows]
            rows = [r[:len(header)] for r in rows]
        labels = _csv_labels(header, path)
    if not rows:
        _fail(path, "no data rows")
    width = max(len(r) for r in rows)
    values = np.full((len(rows), width), np.nan)
    for i, row in enumerate(rows):
        for k, cell in enumerate(row):
            cell = cell.strip()
            if not cell:
                continue
            if not _is_number(cell):
                _fail(path, f"row {i + 1 + (labels is not None)}, column {k + 1}: {cell!r} is "
                            f"not a number")
            values[i, k] = float(cell)
    if width % 3:
        _fail(path, f"wrong array shape: {width} columns is not 3 x markers")
    reject_inf(values, path)
    if labels is not None and len(labels) != width // 3:
        _fail(path, f"header names {len(labels)} markers, data has {width // 3}")
    if filled_rows is not None:
        extra["filled"] = _csv_filled(filled_rows, width // 3, path)
    return (values.reshape(len(rows), width // 3, 3), labels, settings.get("rate"),
            settings.get("units"))


def _csv_comments(text: str, path: Path) -> tuple[str, dict]:
    """Leading ``#`` lines removed from ``text``, and the ``rate``, ``units`` and
    ``first_frame`` they set (``key=value`` items separated by ``;`` or ``,``)."""
    settings: dict = {}
    lines = re.findall(r"[^\r\n]*(?:\r\n|\n|\r|$)", text)
    k = 0
    while k < len(lines) and lines[k].lstrip().startswith("#"):
        for item in re.split(r"[;,]", lines[k].lstrip()[1:]):
            key, sep, value = item.partition("=")
            key, value = key.strip().lower(), value.strip()
            if not sep:
                continue
            try:
                if key == "rate":
                    rate = float(re.sub(r"\s*hz$", "", value, flags=re.I))
                    if not (math.isfinite(rate) and rate > 0):
                        raise ValueError(value)
                    settings["rate"] = rate
                elif key == "units" and value:
                    settings["units"] = value
                elif key == "first_frame":
                    settings["first_frame"] = int(value)
            except ValueError:
                _fail(path, f"line {k + 1}: {key}={value!r} is not a valid {key}")
        k += 1
    return "".join(lines[k:]), settings


def _csv_filled(cells: list[str], J: int, path: Path) -> np.ndarray:
    """``(T, J)`` filled samples from the ``filled`` column (1-based marker numbers)."""
    filled = np.zeros((len(cells), J), dtype=bool)
    for t, cell in enumerate(cells):
        for item in cell.split():
            if not item.isdigit() or not 1 <= int(item) <= J:
                _fail(path, f"row {t + 2}: 'filled' lists {item!r}, expected marker numbers "
                            f"1-{J}")
            filled[t, int(item) - 1] = True
    return filled


def _delimiter(text: str) -> str:
    first = re.sub(r'"[^"]*"', "", re.split(r"\r\n|\n|\r", text)[0]) if text else ""
    return max((",", ";", "\t"), key=first.count) if first else ","


def _is_number(cell: str) -> bool:
    cell = cell.strip()
    if not cell:
        return True
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _csv_labels(header: list[str], path: Path) -> list[str]:
    """Marker labels from a header row: ``NAME_X, NAME_Y, NAME_Z`` or ``NAME, '', ''``."""
    cells = [c.strip() for c in header]
    cells += [""] * (-len(cells) % 3)
    labels = []
    for j in range(len(cells) // 3):
        a, b, c = cells[3 * j:3 * j + 3]
        if a and not b and not c:
            labels.append(a)
            continue
        match = _AXIS.match(a)
        name = match.group("name") if match else a
        if not name:
            name = f"M{match.group('num') or j + 1}" if match else f"M{j + 1}"
        labels.append(name)
    return labels


# --------------------------------------------------------------------------------------------
# Writing


def write(seq: MarkerSequence, path, *, layout: str = "tj3") -> None:
    """Write ``seq`` as ``.npy`` (``layout="tj3"`` (T, J, 3), or ``"t3j"`` (T, 3J)), ``.npz``
    (points, labels, rate, units, first_frame and, when a fill made any, filled) or ``.csv`` (a
    comment line ``# rate=...; units=...; first_frame=...``, a header row
    ``LABEL_x,LABEL_y,LABEL_z,...`` (plus ``filled`` when a fill made any samples), then one row
    per frame, empty cells for missing, shortest round-trip decimals), atomically."""
    path = Path(path)
    suffix = path.suffix.lower()
    check_writable(seq, path, (2, 3) if suffix in (".npy", ".npz") else (3,))
    points = seq.points
    if suffix == ".npy":
        if layout not in ("tj3", "t3j"):
            _fail(path, f"layout must be 'tj3' or 't3j', found {layout!r}")
        array = points if layout == "tj3" else points.reshape(seq.n_frames, -1)
        atomic_write(path, lambda handle: np.save(handle, array, allow_pickle=False))
    elif suffix == ".npz":
        filled = _filled(seq)
        more = {"filled": filled} if filled is not None else {}
        atomic_write(path, lambda handle: np.savez(
            handle, points=points, labels=np.array(seq.labels, dtype=str),
            rate=np.float64(seq.rate), units=np.array(seq.units),
            first_frame=np.int64(seq.first_frame), **more))
    elif suffix == ".csv":
        labels = storable_labels(seq.labels, _csv_label, _csv_labels_back, path)
        filled = _filled(seq)
        out = io.StringIO()
        names = [f"{label}_{axis}" for label in labels for axis in "xyz"]
        csv.writer(out, lineterminator="\n").writerow(names + (["filled"] if filled is not None
                                                               else []))
        header = out.getvalue()
        if (filled is None and seq.meta.get("csv_header") is False
                and seq.labels == default_labels(seq.n_markers)):
            header = ""                      # the source CSV had none: do not add one
        units = re.sub(r"[;,#\s]+", "", str(seq.units)) or "mm"
        if units != seq.units:
            warnings.warn(f"{path.name}: units {seq.units!r} written as {units!r} (a CSV comment "
                          "holds no separators or spaces)", stacklevel=3)
        comment = f"# rate={float(seq.rate)!r}; units={units}; first_frame={seq.first_frame}\n"
        rows = points.reshape(seq.n_frames, -1).tolist()
        body = [",".join("" if v != v else repr(v) for v in row) for row in rows]
        if filled is not None:
            body = [line + "," + " ".join(str(j + 1) for j in np.flatnonzero(f))
                    for line, f in zip(body, filled)]
        text = comment + header + "\n".join(body) + "\n"
        atomic_write(path, lambda handle: handle.write(text.encode("utf-8")))
    else:
        _fail(path, f"unsupported array file type {path.suffix!r}")


def _filled(seq: MarkerSequence) -> np.ndarray | None:
    """``meta["filled"]`` restricted to finite samples, or None when it marks none."""
    filled = seq.meta.get("filled")
    if filled is None or np.shape(filled) != seq.points.shape[:2]:
        return None
    filled = np.asarray(filled, dtype=bool) & np.isfinite(seq.points).all(axis=2)
    return filled if filled.any() else None


def _csv_label(label: str, j: int) -> str:
    """A label as a CSV header name: no line breaks, no outer spaces, never empty."""
    return re.sub(r"[\r\n]+", " ", label).strip() or f"M{j + 1}"


def _csv_labels_back(stored: list[str]) -> list[str]:
    return _csv_labels([f"{label}_{axis}" for label in stored for axis in "xyz"], Path("."))


__all__ = ["read", "write"]
