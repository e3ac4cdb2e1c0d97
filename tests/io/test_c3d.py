"""C3D: every shared file reads and agrees with independent readers; a write-back changes exactly
the filled samples' bytes; fresh files are valid C3D."""
from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest

import torchfill
from torchfill.io import c3d as tc3d

from iohelpers import data_files, linear_fill, longest_run, synthetic

C3D_FILES = data_files(".c3d")
ids = [p.name for p in C3D_FILES]


def _reference_ezc3d(path):
    ezc3d = pytest.importorskip("ezc3d")
    c = ezc3d.c3d(str(path))
    xyz = np.asarray(c["data"]["points"][:3], dtype=np.float64).transpose(2, 1, 0)
    return xyz, list(c["parameters"]["POINT"]["LABELS"]["value"])


def _reference_c3d_package(path):
    c3d = pytest.importorskip("c3d")
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = np.array([p for _, p, _ in c3d.Reader(handle).read_frames()])
    valid = frames[:, :, 3] >= 0
    return np.where(valid[..., None], frames[:, :, :3], np.nan), frames[:, :, 3]


def _missing(xyz):
    return ~np.isfinite(xyz).all(axis=2) | (xyz == 0).all(axis=2)


@pytest.mark.parametrize("path", C3D_FILES, ids=ids)
def test_every_shared_c3d_reads(path):
    seq = torchfill.read(path)
    raw = tc3d.read_raw(path)
    assert seq.points.shape == (raw.layout.n_frames, len(seq.meta["point_index"]), 3)
    assert seq.units in ("mm", "m")
    assert seq.rate > 0 and seq.source == path
    assert all(label == label.strip(" \x00") and label for label in seq.labels)
    assert not any(label.startswith("*") for label in seq.labels)
    assert not np.isinf(seq.points).any()
    # the selected markers are exactly the raw points at point_index, and nothing else is lost
    np.testing.assert_array_equal(seq.points, raw.xyz[:, seq.meta["point_index"]])
    excluded = {i for i, _, _ in seq.meta["excluded"]}
    assert excluded.isdisjoint(seq.meta["point_index"])
    assert len(excluded) + seq.n_markers == raw.layout.n_points


@pytest.mark.parametrize("path", [p for p in C3D_FILES if p.name != "c3dorg_s28_type1.c3d"],
                         ids=[n for n in ids if n != "c3dorg_s28_type1.c3d"])
def test_points_match_ezc3d(path):
    # ezc3d misreads c3dorg_s28_type1.c3d (no ANALOG:RATE, so it drops the 6 analog words per
    # frame that header word 3 declares and the file size confirms); the c3d package test covers it
    raw = tc3d.read_raw(path)
    xyz, labels = _reference_ezc3d(path)
    assert [label.strip() for label in labels[:raw.layout.n_points]] == raw.labels
    np.testing.assert_array_equal(_missing(xyz), ~raw.valid)
    scale = 1e-6 if raw.layout.is_float else abs(raw.layout.scale) * 1e-3
    np.testing.assert_allclose(raw.xyz[raw.valid], xyz[raw.valid], rtol=1e-6, atol=scale)


@pytest.mark.parametrize("path", [p for p in C3D_FILES if p.stat().st_size < 1_000_000
                                  and p.name != "ktk_racing_full.c3d"],
                         ids=[p.name for p in C3D_FILES if p.stat().st_size < 1_000_000
                              and p.name != "ktk_racing_full.c3d"])
def test_points_and_residuals_match_c3d_package(path):
    raw = tc3d.read_raw(path)
    xyz, residual = _reference_c3d_package(path)
    np.testing.assert_array_equal(_missing(xyz), ~raw.valid)
    np.testing.assert_allclose(raw.xyz[raw.valid], xyz[raw.valid], rtol=1e-6,
                               atol=abs(raw.layout.scale) * 1e-3)
    ok = raw.valid
    np.testing.assert_allclose(raw.residual[ok], residual[ok], rtol=1e-6, atol=1e-6)


def test_racing_full_reads_where_the_c3d_package_cannot(recording):
    seq = torchfill.read(recording("ktk_racing_full.c3d"))
    assert seq.points.shape == (700, 46, 3) and seq.units == "m"
    assert seq.rate == pytest.approx(69.9926, abs=1e-3)
    never = seq.mask.all(axis=0)
    assert [seq.labels[j] for j in np.flatnonzero(never)] == [f"Probe{k}" for k in range(1, 7)]


def test_model_outputs_and_copies_are_excluded(recording):
    walk = torchfill.read(recording("ktk_walk.c3d"))
    assert walk.labels == ["LASI", "RASI", "LPSI", "RPSI", "LTHI2", "LTHI", "LKNE", "LTIB", "LANK",
                           "LHEE", "LTOE", "RTHI2", "RTHI", "RKNE", "RTIB", "RANK", "RHEE", "RTOE"]
    everything = torchfill.read(recording("ktk_walk.c3d"), markers_only=False)
    assert everything.n_markers == 96 and everything.meta["excluded"] == []
    hdm = torchfill.read(recording("hdm05_dg_06-03_03_120.c3d"))
    assert hdm.n_markers == 41 and [r[1] for r in hdm.meta["excluded"]] == ["*0", "*1", "*2"]


def test_qualisys_zeros_are_missing(recording):
    path = recording("numediart_03_rolling.c3d")
    raw = tc3d.read_raw(path)
    zeros_valid_word = (raw.word >= 0) & ~raw.valid
    assert zeros_valid_word.sum() > 0                      # gaps stored as (0,0,0), residual >= 0
    seq = torchfill.read(path)
    assert 100 * seq.mask.mean() == pytest.approx(22.95, abs=0.01)


def test_units_without_nul_padding(recording):
    assert torchfill.read(recording("ktk_tennis_serve.c3d")).units == "m"


# ------------------------------------------------------------------------------------------
# Write-back


@pytest.mark.parametrize("path", C3D_FILES + data_files(".trc"),
                         ids=ids + [p.name for p in data_files(".trc")])
def test_unchanged_write_is_byte_identical(path, tmp_path):
    """Byte-identical, except that a C3D gap stored with a valid residual (Qualisys zeros, NaN
    coordinates) is written as missing: zeros and residual -1."""
    out = tmp_path / path.name
    seq = torchfill.read(path)
    torchfill.write(seq, out)
    assert list(tmp_path.iterdir()) == [out]                # no temporary file left
    if path.suffix == ".c3d" and _gaps_marked_valid(path, seq).any():
        _check_write_back(path, out, seq, np.zeros(seq.mask.shape, bool))
        return
    a, b = path.read_bytes().split(b"\n"), out.read_bytes().split(b"\n")
    if path.suffix == ".trc" and a[4] != b[4]:
        # rows ending in a tab (OpenSim's) and an X1 Y1 Z1 line without one: that line gains it,
        # so that pandas (Pose2Sim) reads the columns under their names
        assert b[4] == a[4].rstrip(b"\r") + b"\t" + a[4][len(a[4].rstrip(b"\r")):]
        assert a[6].endswith(b"\t")
        a[4] = b[4]
    assert b"\n".join(b) == b"\n".join(a)


def _gaps_marked_valid(path, seq):
    """(T, J) marker samples missing in the source but stored with a 4th word >= 0."""
    raw = tc3d.read_raw(path)
    cols = np.asarray(seq.meta["point_index"])
    return ~raw.valid[:, cols] & ~(raw.word[:, cols] < 0)


def _sample_spans(lay, filled, index):
    """Byte ranges [start, stop) of the 4 words of every filled sample."""
    t, j = np.nonzero(filled)
    start = lay.data_offset + (t * lay.frame_words + 4 * np.asarray(index)[j]) * lay.word_size
    return start, start + 4 * lay.word_size


def _check_write_back(source, out, seq, filled):
    """Only the bytes of the filled samples and of the gaps stored with a valid residual
    changed; filled samples hold the new values and a 4th word of 0, those gaps zeros and -1."""
    a = np.frombuffer(source.read_bytes(), np.uint8)
    b = np.frombuffer(out.read_bytes(), np.uint8)
    assert a.shape == b.shape
    lay = tc3d.parse(source.read_bytes(), source)
    allowed = np.zeros(a.shape, bool)
    gaps = _gaps_marked_valid(source, seq) & ~filled
    start, stop = _sample_spans(lay, filled | gaps, seq.meta["point_index"])
    allowed[(start[:, None] + np.arange(4 * lay.word_size)).reshape(-1)] = True
    assert not (a != b)[~allowed].any(), "bytes outside the filled samples changed"
    raw = tc3d.read_raw(out)
    cols = np.asarray(seq.meta["point_index"])
    got, word = raw.xyz[:, cols], raw.word[:, cols]
    assert (word[gaps] < 0).all()                          # invalid: residual -1
    block = tc3d.frame_words(out.read_bytes(), lay)[:, :4 * lay.n_points].reshape(
        lay.n_frames, lay.n_points, 4)[:, cols]
    assert (block[gaps][:, :3] == 0).all()                 # and zeros
    assert (word[filled] == 0).all()                       # residual 0, camera mask 0
    assert (raw.residual[:, cols][filled] == 0).all() and (raw.cameras[:, cols][filled] == 0).all()
    tol = abs(lay.scale) / 2 + 1e-9 if not lay.is_float else \
        np.abs(seq.points[filled]).max(initial=1.0) * 2.0 ** -23
    np.testing.assert_allclose(got[filled], seq.points[filled], rtol=0, atol=tol)
    src = tc3d.read_raw(source)
    np.testing.assert_array_equal(raw.valid[:, cols], src.valid[:, cols] | filled)


@pytest.mark.parametrize("path", C3D_FILES, ids=ids)
def test_write_back_changes_only_filled_samples(path, tmp_path):
    """Punch holes in observed data, fill them and the file's own short gaps (NumPy linear
    interpolation, max 60 frames), write back: only those samples' bytes change."""
    seq = torchfill.read(path)
    observed = ~seq.mask
    gappy = seq.points.copy()
    for j in np.argsort(-observed.sum(axis=0), kind="stable")[:3]:
        a, b = longest_run(observed[:, j])                 # a hole inside the longest observed run
        n = min((b - a) // 3, 30)
        gappy[(a + b - n) // 2:(a + b + n) // 2, j] = np.nan
    points, filled = linear_fill(gappy, max_gap=60)
    out_seq = seq.with_points(points)
    out_seq.meta["filled"] = filled
    assert filled.any()
    out = tmp_path / path.name
    torchfill.write(out_seq, out)
    _check_write_back(path, out, out_seq, filled)
    back = torchfill.read(out)
    # the file's own gaps longer than 60 frames were left unfilled: they stay gaps
    np.testing.assert_array_equal(back.mask, seq.mask & ~filled)
    keep = observed & ~filled
    np.testing.assert_array_equal(back.points[keep], seq.points[keep])


@pytest.mark.parametrize("name", ["c3dorg_s02_pc_real.c3d", "c3dorg_s04_sub_labels.c3d"])
def test_torchfill_fill_then_write(name, recording, tmp_path):
    """The real pipeline: read, fill(), write; meta['filled'] from fill() drives the write-back."""
    path = recording(name)
    seq = torchfill.read(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                    # never-observed markers stay empty
        out_seq = torchfill.fill(seq, "linear", constraints=False)   # every gap filled
    filled = out_seq.meta["filled"]
    prior = seq.meta.get("filled", np.zeros(seq.mask.shape, bool))   # residual 0 in the file
    np.testing.assert_array_equal(filled, (seq.mask & ~seq.mask.all(axis=0)) | prior)
    out = tmp_path / name
    torchfill.write(out_seq, out)
    _check_write_back(path, out, out_seq, filled)


def test_hand_set_values_in_integer_dec_file(recording, tmp_path):
    """DEC int16 storage: new values land on the scale grid, nothing else moves."""
    path = recording("biomechzoo_hockey_wrist_shot_009.c3d")
    seq = torchfill.read(path)
    assert seq.meta["c3d"]["processor"] == "dec" and seq.meta["c3d"]["format"] == "int16"
    new = seq.points.copy()
    filled = np.zeros(seq.mask.shape, bool)
    filled[100:110, 4] = True
    new[filled] += 12.3456
    edited = seq.with_points(new)
    edited.meta["filled"] = filled
    out = tmp_path / "edited.c3d"
    torchfill.write(edited, out)
    _check_write_back(path, out, edited, filled)


def test_unfilled_edits_are_not_written_and_warned(recording, tmp_path):
    path = recording("hdm05_dg_06-03_03_120.c3d")
    seq = torchfill.read(path)
    moved = seq.points.copy()
    moved[5, 0] += 1.0                                     # an observed sample, not filled
    with pytest.warns(UserWarning, match="1 sample"):
        torchfill.write(seq.with_points(moved), tmp_path / "x.c3d")
    assert (tmp_path / "x.c3d").read_bytes() == path.read_bytes()


def test_write_back_onto_the_source_itself(recording, tmp_path):
    src = recording("c3dorg_s02_pc_real.c3d")
    path = tmp_path / src.name
    path.write_bytes(src.read_bytes())
    seq = torchfill.read(path)
    filled = torchfill.fill(seq, "linear", extrapolate=None)
    torchfill.write(filled, path)                          # in place: read first, then replace
    assert not torchfill.read(path).mask.any()


def test_integer_overflow_leaves_that_sample_unfilled_and_says_where(recording, tmp_path):
    """One value beyond int16 x scale no longer sinks the whole write; the other
    filled samples are written, the one that does not fit stays invalid, a warning names it."""
    path = recording("biomechzoo_hockey_wrist_shot_009.c3d")
    seq = torchfill.read(path)
    new = seq.points.copy()
    filled = np.zeros(seq.mask.shape, bool)
    filled[100:110, 4] = True
    new[filled] += 12.3456
    new[0, 0] = 1e9                                        # beyond int16 x scale
    filled[0, 0] = True
    edited = seq.with_points(new)
    edited.meta["filled"] = filled
    out = tmp_path / "overflow.c3d"
    with pytest.warns(UserWarning, match=f"1 filled sample.*int16.*{seq.labels[0]} frames "
                                         f"{seq.first_frame}-"):
        torchfill.write(edited, out)
    back = torchfill.read(out)
    np.testing.assert_array_equal(back.points[0, 0], seq.points[0, 0])   # as in the source
    filled[0, 0] = False
    _check_write_back(path, out, edited, filled)


# ------------------------------------------------------------------------------------------
# Fresh files and number formats (no shared data needed)


def test_fresh_c3d_round_trip(tmp_path):
    seq = synthetic()
    out = tmp_path / "fresh.c3d"
    torchfill.write(seq, out)
    back = torchfill.read(out)
    assert back.labels == seq.labels and back.units == "mm" and back.rate == 120.0
    np.testing.assert_array_equal(back.mask, seq.mask)
    np.testing.assert_array_equal(back.points[~seq.mask],
                                  seq.points[~seq.mask].astype(np.float32).astype(np.float64))
    # the fresh file is a C3D that other readers accept
    xyz, labels = _reference_ezc3d(out)
    np.testing.assert_allclose(xyz[~seq.mask], back.points[~seq.mask], rtol=1e-7)
    pkg, _ = _reference_c3d_package(out)
    np.testing.assert_array_equal(np.isnan(pkg).any(axis=2), seq.mask)


def test_fresh_c3d_from_trc_source_keeps_units(tmp_path):
    seq = synthetic(units="m")
    trc = tmp_path / "a.trc"
    torchfill.write(seq, trc)
    out = tmp_path / "a.c3d"
    torchfill.write(torchfill.read(trc), out)
    assert torchfill.read(out).units == "m"


def test_dec_reals_round_trip():
    c3d = pytest.importorskip("c3d")
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(0, 1e3, 200), [0.0, 1.0, -1.0, 0.5, 240.0, 1e-30]])
    words = tc3d._encode_dec(x)
    back = tc3d._decode_real(words, "dec")
    np.testing.assert_array_equal(back[:-1], x[:-1].astype(np.float32).astype(np.float64))
    assert back[-1] == pytest.approx(1e-30, rel=1e-6)
    # the c3d package's DEC decoder agrees (it is exact away from the smallest exponents)
    ref = c3d.c3d.DEC_to_IEEE_BYTES(words.astype("<u4").tobytes())
    np.testing.assert_array_equal(ref[:-1].astype(np.float64), back[:-1])


def _convert(buf: bytes, processor: str) -> bytes:
    """Convert an Intel float C3D (as c3d.Writer makes) to MIPS (big-endian: swap every word) or
    DEC (integers unchanged, reals re-encoded as DEC F-floating)."""
    lay = tc3d.parse(buf, "intel.c3d")
    out = bytearray(buf)

    def real(at, n):
        values = np.frombuffer(buf, "<f4", n, at)
        out[at:at + 4 * n] = (values.astype(">f4").tobytes() if processor == "mips"
                              else tc3d._encode_dec(values).astype("<u4").tobytes())

    def int16(at, n):
        if processor == "mips":
            out[at:at + 2 * n] = np.frombuffer(buf, "<u2", n, at).astype(">u2").tobytes()

    int16(2, 5)
    real(12, 1)
    int16(16, 2)
    real(20, 1)
    start = (buf[0] - 1) * 512
    out[start + 3] = {"mips": 86, "dec": 85}[processor]
    pos = start + 4
    while True:                                            # record headers: offset words
        n = abs(tc3d._s8(buf[pos]))
        if n == 0:
            break
        off = pos + 2 + n
        int16(off, 1)
        step = struct.unpack("<h", buf[off:off + 2])[0]
        if step == 0:
            break
        pos = off + step
    for group in lay.params.values():
        for p in group.values():
            if p.type == 2:
                int16(p.offset, len(p.data) // 2)
            elif p.type == 4:
                real(p.offset, len(p.data) // 4)
    real(lay.data_offset, lay.n_frames * lay.frame_words)
    return bytes(out)


@pytest.mark.parametrize("processor", ["mips", "dec"])
def test_mips_and_dec_float_read_and_write_back(processor, tmp_path):
    seq = synthetic()
    intel = tmp_path / "intel.c3d"
    torchfill.write(seq, intel)
    other = tmp_path / f"{processor}.c3d"
    other.write_bytes(_convert(intel.read_bytes(), processor))
    a, b = torchfill.read(intel), torchfill.read(other)
    assert b.meta["c3d"]["processor"] == processor and b.meta["c3d"]["format"] == "float32"
    assert (b.rate, b.labels, b.units) == (a.rate, a.labels, a.units)
    np.testing.assert_array_equal(b.points, a.points)
    np.testing.assert_array_equal(tc3d.read_raw(other).word, tc3d.read_raw(intel).word)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        filled = torchfill.fill(b, "linear", extrapolate=None)
    out = tmp_path / f"{processor}_filled.c3d"
    torchfill.write(filled, out)
    _check_write_back(other, out, filled, filled.meta["filled"])


def test_write_back_of_a_marker_subset(recording, tmp_path):
    """select() keeps point_index and the filled mask aligned: a subset writes into the right
    points of the source."""
    path = recording("c3dorg_s02_pc_real.c3d")
    seq = torchfill.read(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        filled = torchfill.fill(seq, "linear", extrapolate=None)
    some = [j for j in range(seq.n_markers) if seq.mask[:, j].any()][:4]
    subset = filled.select(some)
    out = tmp_path / "subset.c3d"
    torchfill.write(subset, out)
    _check_write_back(path, out, subset, subset.meta["filled"])
    back = torchfill.read(out)
    assert not back.mask[:, some].any()


@pytest.mark.parametrize("stored,units", [("m\x00\x00\x00", "m"), ("mm  ", "mm"), ("MM", "mm"),
                                          ("", "mm"), ("meters", "m"), ("in", "in")])
def test_units_normalized(stored, units):
    assert tc3d.normalize_units(stored) == units


def test_signalling_nan_in_a_float_file_is_missing_without_a_warning(tmp_path):
    """A data word holding a signalling NaN (a corrupt or hand-edited file) reads as a missing
    sample; casting it raised numpy's 'invalid value' warning on the user's terminal."""
    seq = synthetic(gaps=False)
    path = tmp_path / "snan.c3d"
    torchfill.write(seq, path)
    raw = bytearray(path.read_bytes())
    word = struct.pack("<f", np.float32(seq.points[3, 1, 0]))
    assert raw.count(word) == 1
    at = raw.index(word)
    raw[at:at + 4] = struct.pack("<I", 0x7FA00000)                      # a signalling NaN
    path.write_bytes(bytes(raw))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = torchfill.read(path)
    assert back.mask[3, 1] and back.mask.sum() == 1
    np.testing.assert_array_equal(back.points[~back.mask],
                                  seq.points[~back.mask].astype(np.float32).astype(np.float64))
