"""Small files that claim to be huge: readers check the sizes a header claims against the file
and cap decompression before allocating, so ``torchfill info`` on them is a one-line error in
bounded memory (a 1 KiB C3D claiming 2^32 - 1 frames, an .npz that inflates to 2 GB)."""
from __future__ import annotations

import json
import struct
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill.io import FileFormatError

REPO = Path(__file__).resolve().parents[2]
LIMIT_MB = 300


def _record(name: str, gid: int, body: bytes) -> bytes:
    """One parameter-section record: name length, group id, name, offset to the next record,
    then the body (the offset counts from its own first byte)."""
    raw = name.encode()
    return struct.pack("<bb", len(raw), gid) + raw + struct.pack("<h", 2 + len(body)) + body


def _param(name: str, gid: int, ptype: int, dims: tuple, data: bytes) -> bytes:
    return _record(name, gid, struct.pack("<bB", ptype, len(dims)) + bytes(dims) + data + b"\0")


def c3d_claiming(frames: int, points: int) -> bytes:
    """A 1 KiB Intel float C3D (header + one parameter block, no data) whose TRIAL parameters
    claim ``frames`` frames of ``points`` points."""
    header = bytearray(512)
    header[0], header[1] = 2, 0x50
    struct.pack_into("<HHHH", header, 2, points, 0, 1, min(frames, 0xFFFF))
    struct.pack_into("<fH", header, 12, -1.0, 3)
    struct.pack_into("<f", header, 20, 100.0)
    params = b"".join([
        struct.pack("<BBBB", 1, 80, 1, 84),
        _record("POINT", -1, b"\0"),
        _param("USED", 1, 2, (), struct.pack("<h", points)),
        _param("SCALE", 1, 4, (), struct.pack("<f", -1.0)),
        _param("RATE", 1, 4, (), struct.pack("<f", 100.0)),
        _param("DATA_START", 1, 2, (), struct.pack("<h", 3)),
        _record("TRIAL", -2, b"\0"),
        _param("ACTUAL_START_FIELD", 2, 2, (2,), struct.pack("<HH", 1, 0)),
        _param("ACTUAL_END_FIELD", 2, 2, (2,), struct.pack("<HH", frames & 0xFFFF, frames >> 16)),
    ])
    params += b"\0" * (512 - len(params))
    assert len(params) == 512
    return bytes(header) + params


def npz_bomb(path: Path, inflated: int = 2 << 30) -> None:
    """An .npz whose ``points`` member (float64 zeros, (T, 10, 3)) inflates to ``inflated`` bytes,
    written a chunk at a time (nothing of that size is ever held)."""
    T = inflated // (10 * 3 * 8)
    head = np.lib.format.header_data_from_array_1_0(np.zeros((1, 10, 3)))
    head["shape"] = (T, 10, 3)
    buf = __import__("io").BytesIO()
    np.lib.format.write_array_header_1_0(buf, head)
    chunk = bytes(8 << 20)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        with z.open("points.npy", "w", force_zip64=True) as member:
            member.write(buf.getvalue())
            left = T * 10 * 3 * 8
            while left:
                n = min(left, len(chunk))
                member.write(chunk[:n])
                left -= n


def _info_peak(path: Path) -> tuple[int, str, float]:
    """Exit status, stderr and peak resident memory (MB) of ``torchfill info PATH`` run in a
    child of a fresh interpreter (so that no other child's peak is counted)."""
    probe = (
        "import json, resource, subprocess, sys\n"
        "p = subprocess.run([sys.executable, '-m', 'torchfill', 'info', sys.argv[1]],\n"
        "                   capture_output=True, text=True)\n"
        "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024\n"
        "print(json.dumps([p.returncode, p.stderr, peak]))\n")
    env = {**__import__("os").environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", probe, str(path)], capture_output=True,
                          text=True, env=env, timeout=600)
    return tuple(json.loads(done.stdout))


@pytest.mark.parametrize("points", [0, 1])
def test_c3d_claiming_four_billion_frames(tmp_path, points):
    path = tmp_path / f"claims_{points}.c3d"
    path.write_bytes(c3d_claiming(2**32 - 1, points))
    assert path.stat().st_size == 1024
    with pytest.raises(FileFormatError) as err:
        torchfill.read(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)
    assert ("4294967295 frames declared" in str(err.value)) if points else \
        ("no 3-D points" in str(err.value))
    status, stderr, peak = _info_peak(path)
    assert status == 2 and len(stderr.strip().splitlines()) == 1, stderr
    assert peak <= LIMIT_MB, f"info took {peak:.0f} MB"


def test_the_crafted_c3d_is_otherwise_valid(tmp_path):
    """The generator makes real C3Ds: claiming 2 frames of 1 point, with their data, it reads."""
    path = tmp_path / "two.c3d"
    path.write_bytes(c3d_claiming(2, 1) + struct.pack("<4f", 1, 2, 3, 0) * 2 + bytes(512 - 32))
    seq = torchfill.read(path)
    assert seq.points.shape == (2, 1, 3) and seq.rate == 100.0
    np.testing.assert_array_equal(seq.points[0, 0], [1, 2, 3])


@pytest.mark.slow
def test_npz_inflating_to_2_gb(tmp_path):
    path = tmp_path / "bomb.npz"
    npz_bomb(path)
    size = path.stat().st_size
    assert size < 16 << 20                                # ~9 MB on disk (229x)
    with zipfile.ZipFile(path) as z:
        assert z.getinfo("points.npy").file_size >= 2 << 30
    with pytest.raises(FileFormatError, match="decompression bomb") as err:
        torchfill.read(path)
    assert "\n" not in str(err.value)
    status, stderr, peak = _info_peak(path)
    assert status == 2 and "decompression bomb" in stderr and len(stderr.strip().splitlines()) == 1
    assert peak <= LIMIT_MB, f"info took {peak:.0f} MB"


def test_npz_member_claiming_less_than_it_holds(tmp_path):
    """A member whose .npy header claims more data than the member's size is refused before the
    allocation; a lying zip directory cannot make the reader inflate more than it declares."""
    path = tmp_path / "lie.npz"
    head = np.lib.format.header_data_from_array_1_0(np.zeros((1, 10, 3)))
    head["shape"] = (10**8, 10, 3)
    buf = __import__("io").BytesIO()
    np.lib.format.write_array_header_1_0(buf, head)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("points.npy", buf.getvalue() + bytes(240))
    with pytest.raises(FileFormatError, match="claims shape"):
        torchfill.read(path)
