"""TRC: every shared file reads (doubled header tabs included); a write-back keeps the header and
every untouched cell; fresh files round-trip."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import torchfill

from iohelpers import data_files, linear_fill, longest_run, synthetic

TRC_FILES = data_files(".trc")
EXPECTED = {   # frames, markers, rate, first frame (from each file's header)
    "osim_gait2392_subject01_walk1.trc": (151, 41, 60.0, 1),
    "osim_hamner_subject02_running.trc": (600, 41, 60.0, 1),
    "osim_rajagopal_motion_capture_run.trc": (510, 42, 100.0, 23),
    "osim_rajagopal_motion_capture_walk.trc": (238, 41, 100.0, 1),
}


@pytest.mark.parametrize("path", TRC_FILES, ids=[p.name for p in TRC_FILES])
def test_every_shared_trc_reads(path):
    seq = torchfill.read(path)
    T, J, rate, first = EXPECTED.get(path.name, (seq.n_frames, seq.n_markers, seq.rate,
                                                 seq.first_frame))
    assert seq.points.shape == (T, J, 3)
    assert seq.rate == rate and seq.units == "mm" and seq.first_frame == first
    assert len(set(seq.labels)) == J and all(label.strip() == label for label in seq.labels)
    assert not np.isinf(seq.points).any()


def test_doubled_header_tabs_parse_positionally(recording):
    seq = torchfill.read(recording("osim_rajagopal_motion_capture_walk.trc"))
    assert (seq.n_frames, seq.n_markers, seq.rate, seq.units) == (238, 41, 100.0, "mm")
    assert seq.labels[:2] == ["R.Shoulder", "L.Shoulder"]
    np.testing.assert_allclose(seq.points[0, 0], [-652.630, 1529.542, -94.520])


def test_dead_marker_of_zeros_is_missing(recording):
    seq = torchfill.read(recording("osim_hamner_subject02_running.trc"))
    dead = seq.mask.all(axis=0)
    assert [seq.labels[j] for j in np.flatnonzero(dead)] == ["L.Bicep"]
    kept = torchfill.io.trc.read(recording("osim_hamner_subject02_running.trc"),
                                 zeros_missing=False)
    assert not kept.mask.any()


@pytest.mark.parametrize("path", TRC_FILES, ids=[p.name for p in TRC_FILES])
def test_write_back_changes_only_filled_cells(path, tmp_path):
    seq = torchfill.read(path)
    observed = ~seq.mask
    gappy = seq.points.copy()
    j = int(np.argmax(observed.sum(axis=0)))
    a, b = longest_run(observed[:, j])
    gappy[(a + b) // 2 - 10:(a + b) // 2 + 10, j] = np.nan
    points, filled = linear_fill(gappy, max_gap=60)
    out_seq = seq.with_points(points)
    out_seq.meta["filled"] = filled
    out = tmp_path / path.name
    torchfill.write(out_seq, out)
    src_lines = path.read_bytes().split(b"\n")
    out_lines = out.read_bytes().split(b"\n")
    assert len(src_lines) == len(out_lines)
    data_start = len(src_lines) - seq.n_frames - (src_lines[-1] == b"")
    changed = {i for i, (x, y) in enumerate(zip(src_lines, out_lines)) if x != y}
    rows = {data_start + t for t in np.flatnonzero(filled.any(axis=1))}
    # rows too short for OpenSim are padded with empty cells and a trailing tab (then every row
    # and the X1 Y1 Z1 line get one); their cells stay as they were
    padded = changed - rows - {0}
    for i in padded:
        a, b = src_lines[i].rstrip(b"\r"), out_lines[i].rstrip(b"\r")
        assert b.startswith(a) and not b[len(a):].strip(b"\t") and b.endswith(b"\t")
    assert padded <= {4} | set(range(data_start, data_start + seq.n_frames))
    # the header is byte-identical; the filled samples are recorded beside the file
    assert 0 not in changed
    assert (tmp_path / (path.name + ".filled")).is_file()
    for t in np.flatnonzero(filled.any(axis=1))[:5]:       # within a changed row, only filled cells
        x = src_lines[data_start + t].split(b"\t")
        y = out_lines[data_start + t].split(b"\t")
        cells = {2 + 3 * j + k for j in np.flatnonzero(filled[t]) for k in range(3)}
        assert {i for i in range(len(x)) if x[i] != y[i]} <= cells
    back = torchfill.read(out)
    decimals = len(x[2].split(b".")[1])
    np.testing.assert_allclose(back.points[filled], points[filled], atol=0.51 * 10.0 ** -decimals)
    np.testing.assert_array_equal(back.points[~filled], seq.points[~filled])


def test_fresh_trc_round_trip(tmp_path):
    seq = synthetic()
    out = tmp_path / "fresh.trc"
    torchfill.write(seq, out)
    back = torchfill.read(out)
    assert back.labels == seq.labels and back.rate == seq.rate and back.units == "mm"
    np.testing.assert_array_equal(back.mask, seq.mask)
    np.testing.assert_allclose(back.points[~seq.mask], seq.points[~seq.mask], atol=5e-7)
    # writing it again from its own source, unchanged, reproduces the bytes
    again = tmp_path / "again.trc"
    torchfill.write(back, again)
    assert again.read_bytes() == out.read_bytes()


def test_trc_filling_a_short_row(tmp_path):
    """A row cut short (trailing markers missing) is padded when its samples are filled."""
    seq = synthetic(T=30, J=3, gaps=False)
    seq.points[12:15, 2] = np.nan
    out = tmp_path / "short.trc"
    torchfill.write(seq, out)
    text = out.read_text().split("\n")
    text = [line.rstrip("\t") for line in text]          # rows 12-14 now end after marker 2
    out.write_text("\n".join(text))
    read = torchfill.read(out)
    assert read.mask[12:15, 2].all()
    filled = read.with_points(np.where(read.mask[..., None], 1.5, read.points))
    filled.meta["filled"] = read.mask
    torchfill.write(filled, tmp_path / "filled.trc")
    np.testing.assert_allclose(torchfill.read(tmp_path / "filled.trc").points[12:15, 2], 1.5)


@pytest.mark.parametrize("suffix, label, stored", [
    (".trc", "R\tASIS", "R ASIS"),                          # a tab would split the TRC cell
    (".c3d", "L" * 300, "L" * 255),                         # C3D strings hold 255 bytes
])
def test_what_a_format_cannot_hold_is_changed_with_one_warning_line(tmp_path, suffix, label,
                                                                     stored):
    seq = synthetic(T=10, J=3, gaps=False)
    seq.labels[1] = label
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torchfill.write(seq, tmp_path / f"x{suffix}")
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "\n" not in message and repr(label[:20])[:-1] in message
    assert torchfill.read(tmp_path / f"x{suffix}").labels[1] == stored


def test_control_characters_do_not_end_a_line(tmp_path):
    """Only CR/LF end a TRC line (``str.splitlines`` also breaks at \\x1c-\\x1e, \\x85, ...): a
    cell holding one is a one-line error, not a row split in two."""
    seq = synthetic(T=12, J=2, gaps=False)
    path = tmp_path / "ctl.trc"
    torchfill.write(seq, path)
    lines = path.read_bytes().split(b"\n")
    lines[8] = lines[8].replace(b".", b".\x1e", 1)
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(torchfill.io.FileFormatError, match=r"line 9: .* is not a number"):
        torchfill.read(path)
