"""C3D files: read the markers, and write filled samples back into the source file's bytes.

The file structure is parsed here directly (header, parameter section, data block) with NumPy,
rather than through the ``c3d`` package's frame reader, for three reasons:

* a write-back must know the exact byte offset of every sample, so the layout has to be
  computed here anyway;
* the ``c3d`` package (0.6.0) cannot read ``ktk_racing_full.c3d``: that file stores
  ``ANALOG:SCALE`` as a scalar (zero dimensions) and has ``ANALOG:USED = 0``. The package's
  ``Reader.read_frames()`` always calls ``get_analog_transform()``, whose ``Param.float_array``
  asserts that the parameter has dimensions, so reading any frame raises
  ``AssertionError: SCALE: cannot get value as float32 array`` (the parameter is ANALOG:SCALE,
  not POINT:SCALE, although both hold -1.0). Reading the parameters ourselves avoids it: the
  analog scales are never needed to read or write points;
* one vectorized read of the whole data block is ~100x faster than a Python loop over frames.

The ``c3d`` package is used to write *fresh* files (a sequence with no C3D source).

Conventions (C3D User Guide, C3D.org, 2008, ch. 3-4):

* header: word 1 byte 1 = first parameter block, byte 2 = 0x50; word 2 = points; word 3 = analog
  samples per frame (all channels); words 4-5 = first/last frame; words 7-8 = scale (float);
  word 9 = first data block; words 11-12 = frame rate (float);
* parameter section: 4 bytes (reserved, reserved, number of blocks, processor type 83+n with
  n = 1 Intel, 2 DEC, 3 MIPS), then group and parameter records;
* data: per frame, ``POINT:USED`` x 4 words (x, y, z, residual/camera word), then the analog
  samples; words are float32 when ``POINT:SCALE < 0`` (coordinates stored in file units) and
  int16 otherwise (coordinates = word x scale). The 4th word, read as an integer, is negative for
  an invalid sample; otherwise its low byte x |scale| is the residual and its high byte the mask
  of cameras that saw the marker. Residual 0 with camera mask 0 marks an interpolated sample.
* Intel: little-endian IEEE; MIPS: big-endian IEEE; DEC: little-endian integers and VAX
  F-floating reals, whose bits, with the two 16-bit halves swapped, read as IEEE give 4x the value.

References
----------
.. [1] C3D.org, *The C3D File Format User Guide*, Motion Lab Systems, 2008.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import FileFormatError
from ..sequence import MarkerSequence

PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}

#: POINT parameters that list model outputs (Vicon Plug-in-Gait, pyCGM2, Nexus): angles, forces,
#: moments, powers, scalars, ground reactions and modelled (computed) markers such as joint centres.
#: ``POINT:TYPE_GROUPS`` may name more; those are honoured too.
MODEL_OUTPUT_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS",
                       "MODELED_MARKERS")

#: Suffixes of the four virtual points of a segment coordinate frame written by Plug-in-Gait and
#: pyCGM2: Origin, Anterior, Lateral, Proximal (PELO/PELA/PELL/PELP, LFEMUR_CGM_2.4O/A/L/P, ...).
SEGMENT_FRAME_SUFFIXES = ("O", "A", "L", "P")


# --------------------------------------------------------------------------------------------
# Parsing


@dataclass
class Param:
    """One C3D parameter: its type (-1 char, 1 byte, 2 int16, 4 float), dimensions and raw bytes."""

    group: str
    name: str
    type: int
    dims: tuple[int, ...]
    data: bytes
    offset: int          # byte offset of ``data`` in the file


@dataclass
class Layout:
    """Where everything is in one C3D file (all offsets in bytes from the start of the file)."""

    path: Path
    processor: str
    params: dict[str, dict[str, Param]]
    n_points: int
    n_frames: int
    first_frame: int
    rate: float
    scale: float
    is_float: bool
    data_offset: int
    analog_words: int
    file_size: int
    _endian: str = field(default="<", repr=False)

    @property
    def word_size(self) -> int:
        return 4 if self.is_float else 2

    @property
    def frame_words(self) -> int:
        return 4 * self.n_points + self.analog_words

    @property
    def data_size(self) -> int:
        return self.n_frames * self.frame_words * self.word_size

    @property
    def storage_dtype(self) -> np.dtype:
        """dtype of one stored word (DEC reals are read as raw uint32 and converted)."""
        if not self.is_float:
            return np.dtype(self._endian + "i2")
        return np.dtype("<u4" if self.processor == "dec" else self._endian + "f4")

    def get(self, key: str) -> Param | None:
        group, _, name = key.upper().partition(":")
        return self.params.get(group, {}).get(name)


def _fail(path, problem: str):
    raise FileFormatError(f"{path}: {problem}")


def parse(buf: bytes, path) -> Layout:
    """The :class:`Layout` of a C3D file held in ``buf``; ``FileFormatError`` if it is not one."""
    size = len(buf)
    if size == 0:
        _fail(path, "empty file")
    if _looks_like_text(buf[:256]):
        _fail(path, "not a C3D file (it is text)")
    if size < 512 or buf[1] != 0x50:
        _fail(path, "not a C3D file (no C3D header: byte 2 must be 0x50)")
    param_start = (buf[0] - 1) * 512
    if buf[0] < 2 or param_start + 4 > size:
        _fail(path, f"truncated C3D: parameter block {buf[0]} is beyond the end of the file "
                    f"({size} bytes)")
    code = buf[param_start + 3]
    if code not in PROCESSORS:
        _fail(path, f"unsupported C3D processor type {code} (expected 84 Intel, 85 DEC, 86 MIPS)")
    processor = PROCESSORS[code]
    endian = ">" if processor == "mips" else "<"
    params = _parse_params(buf, param_start, endian, processor, path)
    lay = Layout(path=Path(path), processor=processor, params=params, n_points=0, n_frames=0,
                 first_frame=1, rate=0.0, scale=-1.0, is_float=True, data_offset=0,
                 analog_words=0, file_size=size, _endian=endian)
    header = np.frombuffer(buf, dtype=endian + "u2", count=12)
    h_scale = _decode_real(buf[12:16], processor, endian)[0]
    h_rate = _decode_real(buf[20:24], processor, endian)[0]

    lay.n_points = _uint(lay, "POINT:USED", int(header[1]))
    lay.scale = _real(lay, "POINT:SCALE", h_scale)
    lay.is_float = lay.scale < 0
    lay.rate = _real(lay, "POINT:RATE", h_rate)
    lay.first_frame, lay.n_frames = _frame_range(lay, int(header[3]), int(header[4]))
    data_block = _uint(lay, "POINT:DATA_START", int(header[8])) or int(header[8])
    lay.data_offset = (data_block - 1) * 512
    lay.analog_words = int(header[2])
    if lay.n_points == 0:
        _fail(path, f"no 3-D points in this C3D (POINT:USED is 0; {lay.n_frames} frames of "
                    f"analog data only)" if lay.analog_words else
              "no 3-D points in this C3D (POINT:USED is 0)")
    if data_block < 2 or lay.data_offset < param_start + 4:
        _fail(path, f"corrupt C3D: data block {data_block} overlaps the header or parameters")
    if not np.isfinite(lay.rate) or lay.rate < 0:
        _fail(path, f"corrupt C3D: POINT:RATE is {lay.rate}")
    if not np.isfinite(lay.scale) or lay.scale == 0:
        _fail(path, f"corrupt C3D: POINT:SCALE is {lay.scale}")
    if lay.data_offset + lay.data_size > size:
        have = max(size - lay.data_offset, 0) // max(lay.frame_words * lay.word_size, 1)
        _fail(path, f"truncated C3D: {lay.n_frames} frames declared, data for {have} present "
                    f"({size} bytes)")
    return lay


def _looks_like_text(head: bytes) -> bool:
    """True for printable ASCII/UTF-8 text; a C3D starts with a small block number (byte 1 < 9)."""
    if not head:
        return False
    try:
        text = head.decode("utf-8", errors="strict")
    except UnicodeDecodeError:
        return False
    return all(ch.isprintable() or ch in "\r\n\t" for ch in text)


def _parse_params(buf: bytes, start: int, endian: str, processor: str, path) -> dict:
    """Group and parameter records of the parameter section, as ``{GROUP: {NAME: Param}}``."""
    n_blocks = buf[start + 2]
    end = min(len(buf), start + max(n_blocks, 1) * 512)
    groups: dict[int, str] = {}
    records: list[tuple[int, Param]] = []
    pos = start + 4
    i16 = np.dtype(endian + "i2")
    while pos + 2 <= end:
        name_len, gid = abs(_s8(buf[pos])), _s8(buf[pos + 1])   # negative length: locked
        if name_len == 0:
            break
        off_pos = pos + 2 + name_len
        if off_pos + 2 > end:
            _fail(path, "truncated C3D: parameter section ends inside a record")
        name = buf[pos + 2:off_pos].decode("latin-1").strip().upper()
        offset = int(np.frombuffer(buf, i16, 1, off_pos)[0])
        if gid < 0:
            groups[-gid] = name
        elif gid > 0:
            if off_pos + 4 > end:
                _fail(path, f"truncated C3D: parameter {name} cut off")
            ptype = _s8(buf[off_pos + 2])
            ndim = buf[off_pos + 3]
            dims = tuple(buf[off_pos + 4:off_pos + 4 + ndim])
            if ptype not in (-1, 1, 2, 4):
                _fail(path, f"corrupt C3D: parameter {name} has data type {ptype}")
            data_at = off_pos + 4 + ndim
            n_bytes = abs(ptype) * int(np.prod(dims, dtype=np.int64))
            if data_at + n_bytes > len(buf):
                _fail(path, f"truncated C3D: parameter {name} cut off")
            records.append((gid, Param("", name, ptype, dims, bytes(buf[data_at:data_at + n_bytes]),
                                       data_at)))
        if offset == 0:
            break
        if offset < 0:
            _fail(path, "corrupt C3D: parameter records point backwards")
        pos = off_pos + offset
    params: dict[str, dict[str, Param]] = {name: {} for name in groups.values()}
    for gid, param in records:
        group = groups.get(gid, f"GROUP{gid}")
        param.group = group
        params.setdefault(group, {})[param.name] = param
    return params


def _s8(byte: int) -> int:
    """A byte read as a signed 8-bit integer."""
    return byte - 256 if byte >= 128 else byte


def _param_values(lay: Layout, p: Param) -> np.ndarray:
    """Numeric values of a parameter (flattened), decoded for the file's processor."""
    if p.type == 4:
        return _decode_real(p.data, lay.processor, lay._endian)
    if p.type == 2:
        return np.frombuffer(p.data, lay._endian + "i2").astype(np.int64)
    if p.type == 1:
        return np.frombuffer(p.data, "i1").astype(np.int64)
    return np.zeros(0)


def _uint(lay: Layout, key: str, default: int) -> int:
    p = lay.get(key)
    if p is None or p.type not in (1, 2) or not p.data:
        return default
    value = int(_param_values(lay, p)[0])
    return value & (0xFFFF if p.type == 2 else 0xFF)


def _real(lay: Layout, key: str, default: float) -> float:
    p = lay.get(key)
    if p is None or not p.data or p.type == -1:
        return float(default)
    return float(_param_values(lay, p)[0])


def strings(lay: Layout, key: str) -> list[str]:
    """A character parameter as a list of strings, stripped of spaces and NULs."""
    p = lay.get(key)
    if p is None or p.type != -1:
        return []
    if not p.dims:
        return [_text(p.data)]
    width = p.dims[0]
    raw = p.data
    return [_text(raw[i:i + width]) for i in range(0, len(raw), width)] if width else []


def _text(raw: bytes) -> str:
    """A C3D string: UTF-8 when it decodes as such (torchfill and ezc3d write UTF-8), else
    Latin-1 (older files); spaces and NULs stripped."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.strip(" \x00")


def _frame_range(lay: Layout, first: int, last: int) -> tuple[int, int]:
    """First frame number and frame count: header words 4-5, or TRIAL:ACTUAL_*_FIELD beyond 65535."""
    start, end = lay.get("TRIAL:ACTUAL_START_FIELD"), lay.get("TRIAL:ACTUAL_END_FIELD")
    if start is not None and end is not None and start.type == 2 and end.type == 2:
        s = np.frombuffer(start.data, lay._endian + "u2")
        e = np.frombuffer(end.data, lay._endian + "u2")
        if len(s) >= 2 and len(e) >= 2:
            s_val, e_val = int(s[0]) + 65536 * int(s[1]), int(e[0]) + 65536 * int(e[1])
            if e_val >= s_val and e_val - s_val + 1 > last - first + 1:
                return s_val, e_val - s_val + 1
    if last < first:
        _fail(lay.path, f"corrupt C3D: last frame {last} before first frame {first}")
    return first, last - first + 1


# --------------------------------------------------------------------------------------------
# Reals: IEEE (Intel, MIPS) and DEC


def _decode_real(raw, processor: str, endian: str = "<") -> np.ndarray:
    """float64 values of 32-bit reals stored by ``processor`` (bytes or a uint32 array for DEC)."""
    if processor != "dec":
        return np.frombuffer(raw, endian + "f4").astype(np.float64)
    u = np.frombuffer(raw, "<u4") if isinstance(raw, (bytes, bytearray, memoryview)) else raw
    ieee = ((u >> 16) | (u << 16)).astype(np.uint32)          # swap the 16-bit halves
    value = ieee.view(np.float32).astype(np.float64) / 4.0      # DEC bias: IEEE value / 4
    value[(ieee & 0x7F800000) == 0] = 0.0                       # DEC exponent 0: zero
    return value


def _encode_dec(values: np.ndarray) -> np.ndarray:
    """uint32 words (to store little-endian) holding ``values`` as DEC F-floating reals."""
    x4 = (np.asarray(values, dtype=np.float32) * np.float32(4.0)).astype(np.float32)
    if not np.isfinite(x4).all():
        raise OverflowError("value out of the DEC real range")
    ieee = x4.view(np.uint32).copy()
    ieee[(ieee & 0x7F800000) == 0] = 0                          # zero / too small for DEC
    return ((ieee >> 16) | (ieee << 16)).astype(np.uint32)


# --------------------------------------------------------------------------------------------
# Reading


@dataclass
class RawPoints:
    """Every point of a C3D file as stored: coordinates, validity and the 4th (residual) word."""

    layout: Layout
    labels: list[str]
    xyz: np.ndarray          # (T, P, 3) float64, in file units, NaN where invalid or all-zero
    word: np.ndarray         # (T, P) the 4th word as stored (float32/int16 value)
    valid: np.ndarray        # (T, P) bool: word >= 0, finite and not exactly (0, 0, 0)

    @property
    def residual(self) -> np.ndarray:
        """Residual in file units (low byte x |scale|); -1 where the 4th word is negative."""
        w = np.where(self.word >= 0, self.word, 0).astype(np.int64)
        return np.where(self.word >= 0, (w & 0xFF) * abs(self.layout.scale), -1.0)

    @property
    def cameras(self) -> np.ndarray:
        """Camera contribution mask (high byte of the 4th word); 0 where invalid."""
        w = np.where(self.word >= 0, self.word, 0).astype(np.int64)
        return ((w >> 8) & 0x7F).astype(np.uint8)


def _load(path) -> tuple[bytes, Layout]:
    path = Path(path)
    if not path.is_file():
        _fail(path, "no such file")
    try:
        buf = path.read_bytes()
    except OSError as err:
        raise FileFormatError(f"{path}: cannot read ({err.strerror or err})") from None
    return buf, parse(buf, path)


def frame_words(buf: bytes, lay: Layout) -> np.ndarray:
    """The data block as a ``(T, frame_words)`` array of stored words (a read-only view)."""
    return np.frombuffer(buf, lay.storage_dtype, lay.n_frames * lay.frame_words,
                         lay.data_offset).reshape(lay.n_frames, lay.frame_words)


def read_raw(path) -> RawPoints:
    """All points of a C3D file (markers and model outputs alike) with their 4th words."""
    buf, lay = _load(path)
    return _raw_points(buf, lay)


def _raw_points(buf: bytes, lay: Layout) -> RawPoints:
    T, P = lay.n_frames, lay.n_points
    block = frame_words(buf, lay)[:, :4 * P].reshape(T, P, 4)
    if lay.is_float:
        with np.errstate(invalid="ignore"):       # a signalling NaN in the file is just missing
            values = (_decode_real(block.reshape(-1), "dec") if lay.processor == "dec"
                      else block.reshape(-1).astype(np.float64)).reshape(T, P, 4)
        xyz, word = values[..., :3], values[..., 3]
    else:
        xyz = block[..., :3].astype(np.float64) * lay.scale
        word = block[..., 3].astype(np.float64)
    finite = np.isfinite(xyz).all(axis=2)
    valid = (word >= 0) & finite & ~(xyz == 0).all(axis=2)
    inf = np.isinf(xyz).any(axis=2) & (word >= 0)
    if inf.any():
        t, p = np.argwhere(inf)[0]
        _fail(lay.path, f"infinite coordinate in frame {int(t) + lay.first_frame}, point {int(p)}")
    xyz = np.where(valid[..., None], xyz, np.nan)
    labels = _labels(lay)
    return RawPoints(lay, labels, xyz, word, valid)


def _labels(lay: Layout) -> list[str]:
    """POINT:LABELS, LABELS2, ... (C3D allows 255 per parameter), padded to POINT:USED."""
    labels = strings(lay, "POINT:LABELS")
    k = 2
    while len(labels) < lay.n_points and lay.get(f"POINT:LABELS{k}") is not None:
        labels += strings(lay, f"POINT:LABELS{k}")
        k += 1
    labels = labels[:lay.n_points]
    return labels + [f"POINT{i + 1}" for i in range(len(labels), lay.n_points)]


def non_markers(lay: Layout, labels: list[str]) -> dict[int, str]:
    """Point indices that are not markers, with the reason.

    The rule:

    1. labels listed in a POINT model-output parameter (:data:`MODEL_OUTPUT_GROUPS`, plus any
       named by ``POINT:TYPE_GROUPS``): angles, forces, moments, powers, scalars, reactions and
       modelled markers (joint centres computed by the model, e.g. LKJC);
    2. labels starting with ``*`` (unlabelled points; in HDM05 they are copies of markers);
    3. the four virtual points of a segment coordinate frame (Plug-in-Gait / pyCGM2): a stem
       whose ``O``, ``A``, ``L`` and ``P`` variants are all labels (PELO, PELA, PELL, PELP).

    Points that are merely empty (never observed) stay: they are markers that were lost.
    """
    why: dict[int, str] = {}
    names = set(MODEL_OUTPUT_GROUPS) | {s.upper() for s in strings(lay, "POINT:TYPE_GROUPS")}
    listed = {}
    for name in sorted(names):
        for label in strings(lay, f"POINT:{name}"):
            listed.setdefault(label, name.lower())
    present = set(labels)
    for i, label in enumerate(labels):
        if label in listed:
            why[i] = f"model output ({listed[label]})"
        elif label.startswith("*"):
            why[i] = "unlabelled copy (*)"
        elif label[-1:] in SEGMENT_FRAME_SUFFIXES and len(label) > 1 and all(
                label[:-1] + s in present for s in SEGMENT_FRAME_SUFFIXES):
            why[i] = "segment frame point (O/A/L/P)"
    return why


def read(path, *, markers_only: bool = True) -> MarkerSequence:
    """Read a C3D file into a :class:`MarkerSequence`.

    Parameters
    ----------
    path : str or Path
    markers_only : bool, default True
        Drop points that are not markers (see :func:`non_markers`). They stay in the file on a
        write-back either way.

    Returns
    -------
    MarkerSequence
        ``points`` in the file's units (NaN where the residual is negative, a coordinate is NaN,
        or the sample is exactly (0, 0, 0): Qualisys stores gaps that way); ``meta`` holds
        ``point_index`` (the POINT index of each marker), ``excluded``
        (``[(index, label, reason)]``), ``c3d`` (processor, storage format, scale, number of
        points, analog channels and rate) and, when the file marks any, ``filled``: the (T, J)
        samples stored with a 4th word of 0 (residual 0 and no camera: the C3D mark of an
        interpolated sample), counted only in files whose other samples carry residuals or camera
        masks (many writers store 0 for every sample; there only the -0.0 that torchfill writes
        in IEEE-float files marks a fill); ``verdict``, when torchfill recorded its verdicts in
        the file: (T, J) int8, the code of each filled sample's qc verdict (0 ok, 1 check,
        2 reject; -1 elsewhere; :mod:`torchfill.io.c3d_marks`). ``first_frame`` is the file's
        first frame number.
    """
    path = Path(path)
    buf, lay = _load(path)
    raw = _raw_points(buf, lay)
    dropped = non_markers(lay, raw.labels) if markers_only else {}
    keep = [i for i in range(lay.n_points) if i not in dropped]
    units = normalize_units((strings(lay, "POINT:UNITS") or [""])[0])
    analog_used = _uint(lay, "ANALOG:USED", 0)
    meta = {
        "point_index": keep,
        "excluded": [(i, raw.labels[i], dropped[i]) for i in sorted(dropped)],
        "c3d": {"processor": lay.processor, "format": "float32" if lay.is_float else "int16",
                "scale": lay.scale, "n_points": lay.n_points, "analog_channels": analog_used,
                "analog_rate": _real(lay, "ANALOG:RATE", 0.0) if analog_used else 0.0},
    }
    filled = interpolated(raw)[:, keep]
    if filled.any():
        meta["filled"] = filled
    from .c3d_marks import sample_codes          # it reads this module's layout

    verdict = sample_codes(lay, keep)
    if verdict is not None:
        meta["verdict"] = verdict
    return MarkerSequence(points=raw.xyz[:, keep], labels=[raw.labels[i] for i in keep],
                          rate=lay.rate, units=units, source=path, meta=meta,
                          first_frame=lay.first_frame)


def interpolated(raw: RawPoints) -> np.ndarray:
    """``(T, P)`` valid samples whose 4th word is 0 (residual 0, no camera: interpolated or
    filled, per the C3D convention) in a file whose other valid samples carry residuals or camera
    masks; in a file that stores 0 for every sample, only those stored as -0.0 (torchfill's mark
    of a fill, see :func:`torchfill.io.c3d_write._encode`)."""
    zero = raw.valid & (raw.word == 0)
    if (raw.valid & (raw.word > 0)).any():
        return zero
    return zero & np.signbit(raw.word)          # torchfill's -0.0 (IEEE-float files)


_UNIT_NAMES = {"mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm",
               "millimetres": "mm", "m": "m", "meter": "m", "meters": "m", "metre": "m",
               "metres": "m", "cm": "cm", "centimeter": "cm", "centimeters": "cm"}


def normalize_units(text: str) -> str:
    """POINT:UNITS as 'mm', 'm' or 'cm' when recognisable (any case, NULs and spaces stripped);
    other strings are kept as found, an empty one means 'mm' (the C3D default)."""
    clean = text.strip(" \x00")
    return _UNIT_NAMES.get(clean.lower(), clean) if clean else "mm"


def write(seq: MarkerSequence, path) -> None:
    """Write ``seq`` as a C3D file: see :func:`torchfill.io.c3d_write.write`."""
    from .c3d_write import write as write_c3d     # the writer imports this module's layout

    write_c3d(seq, path)


__all__ = ["Layout", "RawPoints", "non_markers", "parse", "read", "read_raw", "write"]
