"""C3D writing: filled samples back into the source file's bytes, or a fresh file.

The byte layout these writers rely on is parsed in :mod:`torchfill.io.c3d` (the reader); see its
module notes for the C3D conventions.
"""
from __future__ import annotations

import io
import struct
import warnings
from pathlib import Path

import numpy as np

from ._common import atomic_write, check_writable, default_labels, filled_samples, unwritten_edits
from . import c3d_marks
from .c3d import Layout, _encode_dec, _fail, _load, _raw_points, interpolated, parse
from ..sequence import MarkerSequence


def write(seq: MarkerSequence, path) -> None:
    """Write ``seq`` as a C3D file, atomically.

    When ``seq.source`` is a C3D file, the output is that file's bytes with only the filled
    samples changed (x, y, z and the 4th word, set to 0: residual 0 and camera mask 0, the C3D
    mark of an interpolated point; -0.0 in IEEE-float files, see :func:`_encode`) and the
    samples left missing written as missing: a source that stored a gap as (0, 0, 0) with a
    valid residual (Qualisys) gets residual -1 there, so that no reader takes the gap for a
    marker at the origin. Filled samples are ``seq.meta["filled"]`` when present
    (:func:`torchfill.fill` sets it), else the samples invalid in the source and finite in
    ``seq``. Everything else (header, parameters, analog data, events, observed samples and
    their residuals, gaps already marked invalid, points that are not markers) stays
    byte-identical. Other edits to ``seq`` are not written (a warning says how many). For
    integer files the filled coordinates are rounded to the file's scale (``POINT:SCALE``).

    Without a C3D source, a fresh float-format C3D is written with the ``c3d`` package's Writer:
    first frame ``seq.first_frame`` (0, the number of arrays, becomes 1; one the header cannot
    hold becomes 1 with a warning), missing samples residual -1 and zeros, filled
    samples (``meta["filled"]``) residual 0, observed samples residual 1 (the smallest non-zero
    residual: their true residual is unknown, and 0 would mark them as interpolated).
    """
    path = Path(path)
    check_writable(seq, path)
    source = Path(seq.source) if seq.source is not None else None
    if source is not None and source.suffix.lower() == ".c3d" and "point_index" in seq.meta:
        _write_back(seq, path, source)
    else:
        _write_fresh(seq, path)


def _write_back(seq: MarkerSequence, path: Path, source: Path) -> None:
    if not source.is_file():
        _fail(path, f"source file {source} is gone; set seq.source = None to write a fresh C3D")
    buf, lay = _load(source)
    index = np.asarray(seq.meta["point_index"], dtype=np.int64)
    if seq.n_frames != lay.n_frames or len(index) != seq.n_markers:
        _fail(path, f"cannot write back into {source.name}: it has {lay.n_frames} frames, the "
                    f"sequence {seq.n_frames} frames x {seq.n_markers} markers (set "
                    f"seq.source = None to write a fresh C3D)")
    if len(index) and (index.min() < 0 or index.max() >= lay.n_points):
        _fail(path, f"point_index out of range for {source.name} ({lay.n_points} points)")
    raw = _raw_points(buf, lay)
    filled = filled_samples(seq, raw.valid[:, index], path)
    edits = unwritten_edits(seq, raw.xyz[:, index], filled)
    if edits:
        warnings.warn(f"{path.name}: {edits} sample(s) differ from {source.name} but were not "
                      "filled; only filled samples are written back", stacklevel=4)
    out = bytearray(buf)
    words = np.ndarray((lay.n_frames, lay.frame_words), lay.storage_dtype, buffer=out,
                       offset=lay.data_offset)
    # samples the source already holds as filled, unchanged, keep their bytes
    same = interpolated(raw)[:, index] & (seq.points == raw.xyz[:, index]).all(axis=2)
    t, j = np.nonzero(filled & ~same)
    xyz = seq.points[t, j]
    fits = _storable(lay, xyz)
    written = filled.copy()                     # the filled samples the file will hold
    if not fits.all():
        _warn_unstorable(seq, path, source, lay, t[~fits], j[~fits])
        written[t[~fits], j[~fits]] = False
        t, j, xyz = t[fits], j[fits], xyz[fits]
    col = 4 * index[j]
    encoded, zero = _encode(lay, xyz)
    for k in range(3):
        words[t, col + k] = encoded[:, k]
    words[t, col + 3] = zero
    # a sample left missing is written as missing, whatever mark the source used for it (Qualisys
    # stores gaps as (0, 0, 0) with a valid residual, which other readers take for data)
    done = same & filled
    done[t, j] = True
    gone = ~done & ~raw.valid[:, index] & ~(raw.word[:, index] < 0)
    t, j = np.nonzero(gone)
    col = 4 * index[j]
    zeros, invalid = _encode_missing(lay)
    for k in range(3):
        words[t, col + k] = zeros
    words[t, col + 3] = invalid
    out = _marked(seq, bytes(out), lay, path, index, written)
    atomic_write(path, lambda handle: handle.write(out))


def _marked(seq: MarkerSequence, buf: bytes, lay: Layout, path: Path, index, written) -> bytes:
    """``buf`` with the verdicts of ``seq.meta["verdict"]`` on the ``written`` filled samples
    recorded in its TORCHFILL group (:mod:`torchfill.io.c3d_marks`); unchanged without them."""
    codes = seq.meta.get("verdict")
    if codes is None or np.shape(codes) != written.shape:
        return buf
    codes = np.where(written, np.asarray(codes, dtype=np.int8), -1)
    return c3d_marks.with_gaps(buf, lay, path, c3d_marks.runs(codes, np.asarray(index),
                                                                lay.first_frame))


def _storable(lay: Layout, xyz: np.ndarray) -> np.ndarray:
    """``(n,)`` True where a sample's coordinates fit the file's storage (int16 x POINT:SCALE,
    float32, or DEC reals)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if not lay.is_float:
            q = np.rint(xyz / lay.scale)
            return ((q >= -32768) & (q <= 32767)).all(axis=1)
        limit = np.finfo(np.float32).max / (4.0 if lay.processor == "dec" else 1.0)
        return (np.abs(xyz) <= limit).all(axis=1)


def _warn_unstorable(seq, path: Path, source: Path, lay: Layout, t: np.ndarray, j: np.ndarray):
    """One warning naming the markers and frames whose fills the file cannot hold."""
    kind = f"int16 range at POINT:SCALE {lay.scale:g}" if not lay.is_float else "real range"
    where = []
    for m in np.unique(j)[:8]:
        frames = t[j == m] + lay.first_frame
        where.append(f"{seq.labels[m]} frames {frames.min()}-{frames.max()} ({len(frames)})")
    more = " ..." if len(np.unique(j)) > 8 else ""
    warnings.warn(f"{path.name}: {len(t)} filled sample(s) beyond the {kind} of {source.name} "
                  f"left unfilled (residual -1): {'; '.join(where)}{more}; write .trc/.npz/.csv "
                  f"to keep them", stacklevel=4)


def _off_origin(xyz: np.ndarray, step: float) -> np.ndarray:
    """``xyz`` with samples at exactly (0, 0, 0) (which read back as missing: the Qualisys gap
    mark) moved by ``step`` along z, the smallest change the format stores."""
    zero = (xyz == 0).all(axis=1)
    if zero.any():
        xyz = xyz.copy()
        xyz[zero, 2] = step
    return xyz


def _encode(lay: Layout, xyz: np.ndarray) -> tuple[np.ndarray, object]:
    """Stored words for coordinates ``xyz`` (n, 3) and the 4th word of a filled sample, in the
    file's format. The 4th word is 0 (residual 0, no camera: interpolated); in IEEE-float files
    it is -0.0, which every reader takes for 0 but which marks the fill even in files whose
    measured samples also store 0 (:func:`interpolated`)."""
    if lay.is_float:
        xyz = _off_origin(xyz.astype(np.float32).astype(np.float64), 1e-30)
        if lay.processor == "dec":
            return _encode_dec(xyz.reshape(-1)).reshape(xyz.shape), np.uint32(0)
        if np.abs(xyz).max(initial=0.0) > np.finfo(np.float32).max:
            raise OverflowError("value out of the float32 range")
        return xyz.astype(np.float32), np.float32(-0.0)
    q = np.rint(xyz / lay.scale)
    if q.size and (q.min() < -32768 or q.max() > 32767):
        raise OverflowError(f"value beyond the int16 range at POINT:SCALE {lay.scale:g}")
    return _off_origin(q, 1.0).astype(np.int16), np.int16(0)


def _encode_missing(lay: Layout) -> tuple[object, object]:
    """Stored words of a missing sample: coordinates 0 and a 4th word of -1 (C3D: invalid)."""
    if not lay.is_float:
        return np.int16(0), np.int16(-1)
    if lay.processor == "dec":
        return np.uint32(0), _encode_dec(np.array([-1.0]))[0]
    return np.float32(0.0), np.float32(-1.0)


#: C3D dimensions are single bytes: at most 255 strings per parameter, 255 bytes per string.
_C3D_MAX = 255
_C3D_PARAM_BYTES = 32000


def _label_params(labels: list[str], path: Path) -> list[tuple[str, str, bytes, list[int]]]:
    """POINT:LABELS (and LABELS2, LABELS3, ... beyond 255 markers, the C3D convention) and
    DESCRIPTIONS likewise, as UTF-8 strings padded to a common byte width. Labels longer than
    255 bytes are cut (one warning names them)."""
    encoded, cut = [], []
    for label in labels:
        raw = label.encode("utf-8")
        if len(raw) > _C3D_MAX:
            raw = raw[:_C3D_MAX].decode("utf-8", "ignore").encode("utf-8")
            cut.append(label)
        encoded.append(raw)
    if cut:
        warnings.warn(f"{path.name}: {len(cut)} label(s) longer than {_C3D_MAX} bytes cut to fit "
                      f"C3D: {', '.join(repr(c[:20] + '...') for c in cut[:5])}", stacklevel=4)
    params = []
    for k, chunk in enumerate(_chunks(encoded)):
        width = max((len(raw) for raw in chunk), default=1) or 1
        suffix = str(k + 1) if k else ""
        params.append((f"LABELS{suffix}", "Point labels.",
                       b"".join(raw.ljust(width) for raw in chunk), [width, len(chunk)]))
        params.append((f"DESCRIPTIONS{suffix}", "Point descriptions.", b" " * len(chunk),
                       [1, len(chunk)]))
    return params


def _chunks(encoded: list[bytes]) -> list[list[bytes]]:
    """Consecutive labels grouped so that each parameter holds at most 255 strings and
    ``_C3D_PARAM_BYTES`` bytes (a record's size must fit its int16 next-record offset)."""
    chunks: list[list[bytes]] = [[]]
    width = 1
    for raw in encoded:
        wider = max(width, len(raw))
        if chunks[-1] and (len(chunks[-1]) == _C3D_MAX
                           or wider * (len(chunks[-1]) + 1) > _C3D_PARAM_BYTES):
            chunks.append([])
            wider = max(len(raw), 1)
        chunks[-1].append(raw)
        width = wider
    return chunks


def _write_fresh(seq: MarkerSequence, path: Path) -> None:
    """A new float-format C3D (Intel) holding only the markers, via ``c3d.Writer``."""
    import c3d as c3d_package

    T, J = seq.n_frames, seq.n_markers
    labels = seq.labels or default_labels(J)
    writer = c3d_package.Writer(point_rate=float(seq.rate), analog_rate=0.0, point_scale=-1.0,
                                point_units=seq.units or "mm")
    for name, desc, data, dims in _label_params(labels, path):
        writer.point_group.add_param(name, desc=desc, bytes_per_element=-1, bytes=data,
                                     dimensions=dims)
    first = int(seq.first_frame) or 1          # the c3d package writes a first frame 0 as 1
    if first < 0 or (first > 1 and first + T - 1 > 0xFFFF):
        warnings.warn(f"{path.name}: first frame {first} does not fit a C3D header (frames "
                      f"0-65535); written as 1", stacklevel=4)
        first = 1
    writer.set_start_frame(first)
    valid = np.isfinite(seq.points).all(axis=2)
    big = valid & (np.abs(seq.points) > np.finfo(np.float32).max).any(axis=2)
    if big.any():
        t, j = np.argwhere(big)[0]
        _fail(path, f"{int(big.sum())} sample(s) beyond the float32 range of C3D (first: "
                    f"{labels[j]}, frame {first + t}); write .npz, .csv or .trc instead")
    frames = np.zeros((T, J, 5), dtype=np.float32)
    frames[..., :3] = np.where(valid[..., None], seq.points, 0.0)
    frames[valid, :3] = _off_origin(frames[valid, :3].astype(np.float64), 1e-30)
    filled = np.asarray(seq.meta.get("filled", np.zeros_like(valid)), dtype=bool)
    if filled.shape != valid.shape:
        filled = np.zeros_like(valid)
    frames[..., 3] = np.where(valid, np.where(filled, 0.0, 1.0), -1.0)
    analog = np.zeros((0, 1), dtype=np.float32)
    writer.add_frames([(frames[t], analog) for t in range(T)])
    handle = io.BytesIO()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "No analog data found")
        try:
            writer.write(handle)
        except struct.error as err:      # e.g. a parameter section beyond 255 blocks
            _fail(path, f"too many markers or labels too long for a C3D ({err})")
    buf = handle.getvalue()
    buf = _marked(seq, buf, parse(buf, path), path, np.arange(J), valid & filled)
    atomic_write(path, lambda out: out.write(buf))


__all__ = ["write"]
