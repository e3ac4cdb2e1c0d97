"""The fill's per-gap verdicts inside a C3D file: the ``TORCHFILL`` parameter group.

A filled sample is written as a valid point with residual 0 (the C3D mark of an interpolated
sample: a residual >= 0 is data to every reader, -1 a gap), whatever its verdict: a residual
cannot say more without turning the fill into a measurement or into a gap. The verdicts go in a parameter group of their own, which readers that do not know it skip
(docs/files.md, "The fill's verdicts in the written file"):

* ``TORCHFILL:VERDICTS`` (char): the names of the codes, ``ok``, ``check``, ``reject``;
* ``TORCHFILL:GAPS`` (real, dimensions 4 x n; ``GAPS2``, ``GAPS3``, ... beyond 255 runs, as
  POINT:LABELS2): per run of filled samples of one point with one verdict, the point's number
  (1-based, POINT:LABELS order), its first and last frame (the file's numbering) and the
  verdict's code (0, 1, 2).

In ``MarkerSequence.meta`` the same information is ``verdict``: a (T, J) int8 array, the code of
each filled sample's verdict and -1 elsewhere.
"""
from __future__ import annotations

import math
import struct
import warnings
from pathlib import Path

import numpy as np

from .c3d import Layout, _encode_dec, _fail, _param_values, _s8

GROUP = "TORCHFILL"
#: The verdicts' names by code (the order of :data:`torchfill.qc.VERDICTS`).
VERDICT_NAMES = ("ok", "check", "reject")
#: Runs per GAPS parameter (a C3D dimension is one byte).
_PER_PARAM = 255
#: Parameter blocks a file can declare (one byte in the parameter section's header).
_MAX_BLOCKS = 255


def sample_codes(lay: Layout, keep: list[int]) -> np.ndarray | None:
    """``(T, len(keep))`` int8 verdict codes recorded in the file for the points ``keep`` (-1
    where none), or None when the file has no ``TORCHFILL:GAPS``."""
    if lay.get(f"{GROUP}:GAPS") is None:
        return None
    column = {p: i for i, p in enumerate(keep)}
    out = np.full((lay.n_frames, len(keep)), -1, dtype=np.int8)
    k = 1
    while (p := lay.get(f"{GROUP}:GAPS{k if k > 1 else ''}")) is not None:
        if p.type == 4 and len(p.dims) == 2 and p.dims[0] == 4:
            for point, first, last, code in _param_values(lay, p).reshape(-1, 4):
                j = column.get(int(point) - 1)
                a, b = int(first) - lay.first_frame, int(last) - lay.first_frame + 1
                if j is not None and 0 <= a < b <= lay.n_frames and 0 <= code < 3:
                    out[a:b, j] = int(code)
        k += 1
    return out


def runs(codes: np.ndarray, points: np.ndarray, first_frame: int) -> np.ndarray:
    """``(n, 4)`` float rows (point number, first frame, last frame, code) of the runs of equal
    code >= 0 down each column of ``codes`` (T, J); column j is point ``points[j]`` (0-based);
    rejects first, then checks, then ok."""
    rows = []
    for j in np.flatnonzero((codes >= 0).any(axis=0)):
        c = codes[:, j].astype(np.int16)
        edges = np.flatnonzero(np.diff(np.r_[-1, c, -1]) != 0)
        for a, b in zip(edges[:-1], edges[1:]):
            if c[a] >= 0:
                rows.append((points[j] + 1, first_frame + a, first_frame + b - 1, c[a]))
    out = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return out[np.argsort(-out[:, 3], kind="stable")]


def with_gaps(buf: bytes, lay: Layout, path: Path, rows: np.ndarray) -> bytes:
    """``buf`` with its ``TORCHFILL`` group (if any) replaced by one recording ``rows`` (see
    :func:`runs`); the data block moves down when the parameter section must grow (header word
    9 and POINT:DATA_START follow it). Every other parameter keeps its bytes. Runs the section
    cannot hold are left out, ok ones first, with a warning."""
    start = (buf[0] - 1) * 512
    spans = _spans(buf, start, lay.data_offset)
    kept = [s for s in spans if s[3] != GROUP.encode()]
    gid = _group_id(spans)
    size = 4 + sum(b - a for a, b, _, _ in kept)
    n = len(rows)
    while True:
        records = _records(rows[:n], gid, lay)
        blocks = math.ceil((size + len(records)) / 512)
        if blocks <= _MAX_BLOCKS or n == 0:
            break
        n = int(n * 0.9)
    if n < len(rows):
        warnings.warn(f"{path.name}: {len(rows) - n} of {len(rows)} verdict run(s) left out of the "
                      f"{GROUP} group (the parameter section is full)", stacklevel=5)
    body = b"".join(_chained(buf, a, b, lay) for a, b, _, _ in kept) + records
    room = (lay.data_offset - start) // 512
    head = bytearray(buf[start:start + 4])
    head[2] = max(min(buf[start + 2], room), blocks)
    section = bytes(head) + body
    if blocks <= room:
        section += bytes(lay.data_offset - start - len(section))
        return buf[:start] + section + buf[lay.data_offset:]
    section += bytes(blocks * 512 - len(section))
    out = bytearray(buf[:start] + section + buf[lay.data_offset:])
    block = (start + blocks * 512) // 512 + 1
    if block > 0xFFFF:
        _fail(path, "the parameter section cannot grow: the data would start beyond block 65535")
    struct.pack_into(lay._endian + "H", out, 16, block)
    _set_data_start(out, start, lay, block)
    return bytes(out)


def _spans(buf: bytes, start: int, stop: int) -> list[tuple[int, int, int, bytes]]:
    """The records of the parameter section: ``(first byte, end, group id, group name)``; a
    record ends where the next begins, the last where its content ends."""
    end = min(len(buf), stop, start + max(buf[start + 2], 1) * 512)
    raw, names, pos = [], {}, start + 4
    while pos + 2 <= end:
        n, gid = abs(_s8(buf[pos])), _s8(buf[pos + 1])
        if n == 0:
            break
        off = pos + 2 + n
        name = bytes(buf[pos + 2:off]).strip().upper()
        offset = struct.unpack_from(">h" if buf[start + 3] == 86 else "<h", buf, off)[0]
        if gid < 0:
            names[-gid] = name
            last = off + 3 + buf[off + 2]
        else:
            nd = buf[off + 3]
            data = off + 4 + nd + abs(_s8(buf[off + 2])) * int(np.prod(list(buf[off + 4:off + 4 + nd])))
            last = data + 1 + buf[data]
        raw.append((pos, off + offset if offset > 0 else min(last, end), gid))
        if offset <= 0:
            break
        pos = off + offset
    return [(a, b, g, names.get(abs(g), b"")) for a, b, g in raw]


def _chained(buf: bytes, a: int, b: int, lay: Layout) -> bytes:
    """A record's bytes with its offset pointing just past it (unchanged for every record but
    the section's last)."""
    rec = bytearray(buf[a:b])
    n = abs(_s8(rec[0]))
    struct.pack_into(lay._endian + "h", rec, 2 + n, len(rec) - 2 - n)
    return bytes(rec)


def _group_id(spans) -> int:
    """The id of an existing TORCHFILL group, else the smallest id no group uses."""
    used = {abs(g): name for _, _, g, name in spans}
    for gid, name in used.items():
        if name == GROUP.encode():
            return gid
    return next(g for g in range(1, 128) if g not in used)


def _records(rows: np.ndarray, gid: int, lay: Layout) -> bytes:
    """The group record, VERDICTS and GAPS, GAPS2, ... (the last record's offset 0)."""
    width = max(map(len, VERDICT_NAMES))
    names = b"".join(v.encode().ljust(width) for v in VERDICT_NAMES)
    e = lay._endian
    recs = [_record(GROUP, -gid, b"", b"per-gap qc verdicts of a torchfill fill", e),
            _record("VERDICTS", gid, _head(-1, (width, len(VERDICT_NAMES))) + names,
                    b"verdict names by code", e)]
    for k in range(0, max(len(rows), 1), _PER_PARAM):
        part = rows[k:k + _PER_PARAM]
        recs.append(_record(f"GAPS{k // _PER_PARAM + 1 if k else ''}", gid,
                            _head(4, (4, len(part))) + _reals(part.reshape(-1), lay),
                            b"point number, first frame, last frame, verdict code", e))
    last = bytearray(recs[-1])
    struct.pack_into(e + "h", last, 2 + last[0], 0)           # the section's last record
    return b"".join(recs[:-1]) + bytes(last)


def _head(ptype: int, dims: tuple) -> bytes:
    return bytes([ptype & 0xFF, len(dims), *dims])


def _record(name: str, gid: int, content: bytes, desc: bytes, endian: str) -> bytes:
    """One group (``gid`` < 0) or parameter record, its offset pointing just past it."""
    n = name.encode()
    body = content + bytes([len(desc)]) + desc
    return bytes([len(n), gid & 0xFF]) + n + struct.pack(endian + "h", 2 + len(body)) + body


def _reals(values: np.ndarray, lay: Layout) -> bytes:
    if lay.processor == "dec":
        return _encode_dec(values).astype("<u4").tobytes()
    return np.asarray(values, dtype=lay._endian + "f4").tobytes()


def _set_data_start(out: bytearray, start: int, lay: Layout, block: int) -> None:
    """POINT:DATA_START (when the file has one) set to ``block``."""
    for a, _, g, group in _spans(out, start, len(out)):
        n = abs(_s8(out[a]))
        if g > 0 and group == b"POINT" and bytes(out[a + 2:a + 2 + n]).upper() == b"DATA_START":
            off = a + 2 + n
            if _s8(out[off + 2]) == 2:
                struct.pack_into(lay._endian + "H", out, off + 4 + out[off + 3], block)


__all__ = ["GROUP", "VERDICT_NAMES", "runs", "sample_codes", "with_gaps"]
