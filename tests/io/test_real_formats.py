"""Every real recording: fill -> write (C3D, TRC, CSV, NPZ) -> read with an independent reader
(ezc3d and the ``c3d`` package for C3D, plain text parsing for TRC and CSV, NumPy for NPZ).
Observed samples come back bit for bit, unfilled samples are missing in that reader (never a
marker at the origin), and the counts are the fill's own.

A recording without gaps gets some (the last 15 % of its first marker, 10 frames of a middle
one) and is written as a fresh file; a gapped one is written back into its source where the
format is the source's own."""
from __future__ import annotations

import csv
import warnings

import numpy as np
import pytest

import torchfill
from torchfill.sequence import MarkerSequence

from iohelpers import data_files

FILES = [p for p in data_files(".c3d", ".trc", ".csv")]
FORMATS = (".c3d", ".trc", ".csv", ".npz")
BIG = 100_000                      # frames x markers above which a file's cases are slow


def _cases():
    for path in FILES:
        try:
            import ezc3d  # noqa: F401
            size = _size(path)
        except Exception:          # noqa: BLE001 - a file the readers refuse is another test's
            size = 0
        for fmt in FORMATS:
            marks = [pytest.mark.slow] if size > BIG else []
            yield pytest.param(path, fmt, marks=marks, id=f"{path.name}->{fmt[1:]}")


def _size(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = torchfill.read(path)
    return seq.n_frames * seq.n_markers


_FILLS: dict = {}


def _fill(path):
    """(input, fill) for a recording, computed once: linear fill with the default constraints
    and extrapolation limit (so some trial-end samples stay unfilled)."""
    if path not in _FILLS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            seq = torchfill.read(path)
            if not seq.mask.any():                        # complete: punch gaps, write fresh
                P = seq.points.copy()
                P[int(0.85 * seq.n_frames):, 0] = np.nan
                mid = seq.n_frames // 2
                P[mid:mid + 10, seq.n_markers // 2] = np.nan
                seq = MarkerSequence(points=P, labels=seq.labels, rate=seq.rate,
                                     units=seq.units, first_frame=seq.first_frame)
            out = torchfill.fill(seq, "linear")
        _FILLS[path] = (seq, out)
    return _FILLS[path]


# -- independent readers: (labels, points (T, J, 3) NaN where missing, extra) -------------------
def _ezc3d(path, seq):
    ezc3d = pytest.importorskip("ezc3d")
    c = ezc3d.c3d(str(path))
    labels = [label.strip() for label in c["parameters"]["POINT"]["LABELS"]["value"]]
    cols = [labels.index(label) for label in seq.labels]
    P = np.asarray(c["data"]["points"][:3], dtype=np.float64).transpose(2, 1, 0)[:, cols]
    residual = np.asarray(c["data"]["meta_points"]["residuals"][0]).T[:, cols]
    return P, residual


def _c3d_package(path, seq):
    c3d = pytest.importorskip("c3d")
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(handle)
        labels = [label.strip() for label in reader.point_labels]
        frames = np.array([p for _, p, _ in reader.read_frames()])
    cols = [labels.index(label) for label in seq.labels]
    frames = frames[:, cols]
    valid = frames[:, :, 3] >= 0
    return np.where(valid[..., None], frames[:, :, :3], np.nan), frames[:, :, 3]


def _trc_text(path):
    lines = path.read_text(encoding="utf-8").split("\n")
    names = lines[3].split("\t")
    labels = [c.strip() for c in names[2:] if c.strip()]
    J = len(labels)
    rows = [line.rstrip("\r") for line in lines[5:] if line.strip()]
    P = np.full((len(rows), J, 3), np.nan)
    frames = []
    for t, row in enumerate(rows):
        cells = row.split("\t")
        assert len(cells) >= 2 + 3 * J, f"row {t} shortened"       # never a short row
        if not cells[2 + 3 * J - 1].strip():
            assert len(cells) > 2 + 3 * J, f"row {t} ends in an empty cell without a tab"
        frames.append(int(cells[0]))
        for k, cell in enumerate(cells[2:2 + 3 * J]):
            if cell.strip():
                P[t, k // 3, k % 3] = float(cell)
    return labels, P, frames


def _csv_text(path):
    with open(path, newline="", encoding="utf-8") as handle:
        text = [line for line in handle if not line.startswith("#")]
    rows = list(csv.reader(text))
    header, rows = rows[0], rows[1:]
    filled_col = header[-1] == "filled"
    n = len(header) - filled_col
    P = np.array([[float(c) if c.strip() else np.nan for c in r[:n]] for r in rows])
    return header, P.reshape(len(rows), n // 3, 3)


def _same_as_stored(got, want, c3d, same_kind):
    """A TRC holds the values a C3D stored at the C3D's precision: its float32 numbers (the
    shortest text that reads back as the same float32) or its integers times POINT:SCALE."""
    if same_kind or c3d is None:
        np.testing.assert_array_equal(got, want)
    elif c3d["format"] == "float32":
        np.testing.assert_array_equal(got.astype(np.float32), want.astype(np.float32))
    else:
        scale = abs(c3d["scale"])
        np.testing.assert_array_equal(np.rint(got / scale), np.rint(want / scale))


@pytest.mark.parametrize("path, fmt", list(_cases()))
def test_fill_write_read_independently(path, fmt, tmp_path):
    seq, out = _fill(path)
    missing_in = seq.mask
    unfilled, filled_now = out.mask, out.meta["filled"] & missing_in
    assert filled_now.sum() + unfilled.sum() == missing_in.sum()   # the fill's own report
    target = tmp_path / f"out{fmt}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torchfill.write(out, target)
    observed = ~missing_in
    same_kind = seq.source is not None and seq.source.suffix.lower() == fmt
    if fmt == ".c3d":
        readers = [_ezc3d]
        if path.name != "ktk_racing_full.c3d":                 # the c3d package cannot read it
            readers.append(_c3d_package)
        if path.name == "c3dorg_s28_type1.c3d" and same_kind:  # ezc3d misreads this layout
            readers.remove(_ezc3d)
        for reader in readers:
            P, residual = reader(target, seq)
            assert (~np.isfinite(P).all(axis=2) == unfilled).all()
            assert (residual[unfilled] < 0).all()               # residual -1: invalid
            assert not (P[~unfilled] == 0).all(axis=1).any()    # no marker at the origin
            if same_kind and seq.meta["c3d"]["format"] == "int16":
                tol = abs(seq.meta["c3d"]["scale"]) * 1e-4
                np.testing.assert_allclose(P[observed], seq.points[observed], rtol=2.0 ** -22,
                                           atol=tol)            # ezc3d scales in float32
            else:
                want = seq.points[observed]
                if not same_kind:
                    want = want.astype(np.float32).astype(np.float64)
                np.testing.assert_array_equal(P[observed], want)
            if not same_kind and reader is _c3d_package:
                # fresh: residual 0 = filled (ezc3d takes the residual from the other byte)
                assert ((residual == 0) == out.meta["filled"]).all()
    elif fmt == ".trc":
        labels, P, frames = _trc_text(target)
        assert labels == out.labels
        assert frames == list(range(seq.first_frame, seq.first_frame + seq.n_frames))
        if same_kind:                                           # zeros mark a dead marker there
            P[(P == 0).all(axis=2)] = np.nan
        np.testing.assert_array_equal(~np.isfinite(P).all(axis=2), unfilled)
        _same_as_stored(P[observed], seq.points[observed], seq.meta.get("c3d"), same_kind)
    elif fmt == ".csv":
        header, P = _csv_text(target)
        np.testing.assert_array_equal(~np.isfinite(P).all(axis=2), unfilled)
        np.testing.assert_array_equal(P[observed], seq.points[observed])
        np.testing.assert_array_equal(P[filled_now], out.points[filled_now])
    else:
        with np.load(target, allow_pickle=False) as z:
            P = z["points"]
            assert float(z["rate"]) == seq.rate and str(z["units"]) == seq.units
            assert int(z["first_frame"]) == seq.first_frame
            if out.meta["filled"].any():
                np.testing.assert_array_equal(z["filled"], out.meta["filled"])
            else:
                assert "filled" not in z.files
        np.testing.assert_array_equal(np.isnan(P).any(axis=2), unfilled)
        np.testing.assert_array_equal(P[observed], seq.points[observed])
        np.testing.assert_array_equal(P[filled_now], out.points[filled_now])
    # and torchfill reads back what it wrote: the same gaps, the filled samples marked
    back = torchfill.read(target)
    np.testing.assert_array_equal(back.mask, unfilled)
    assert back.first_frame == (seq.first_frame or (1 if fmt == ".c3d" and not same_kind else 0))
    if fmt != ".c3d" or back.meta.get("c3d", {}).get("format") == "float32":
        np.testing.assert_array_equal(back.meta.get("filled", np.zeros_like(unfilled)),
                                      out.meta["filled"])


@pytest.mark.parametrize("name", ["c3dorg_s26_walking_hybrid_1_1.c3d", "c3dorg_s28_type1.c3d",
                                  "mogapfill_gait-raw.csv"])
@pytest.mark.parametrize("fmt", FORMATS)
def test_cli_summary_counts_what_the_file_holds(recording, tmp_path, capsys, name, fmt):
    """``torchfill fill`` says 'filled N samples ...; M left unfilled': an independent reader of
    the output finds M missing samples and N more present than in the input."""
    from torchfill.cli import main
    path = recording(name)
    out = tmp_path / f"out{fmt}"
    assert main(["fill", str(path), "-o", str(out), "-m", "linear"]) == 0
    said = capsys.readouterr()
    line = [ln for ln in (said.out + said.err).splitlines() if ln.startswith("filled ")][-1]
    n_filled, n_left = int(line.split()[1]), int(line.split("; ")[1].split()[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = torchfill.read(path)
    if fmt == ".c3d":
        P, _ = _c3d_package(out, seq)
    elif fmt == ".trc":
        P = _trc_text(out)[1]
        if seq.source.suffix == ".trc":
            P[(P == 0).all(axis=2)] = np.nan
    elif fmt == ".csv":
        P = _csv_text(out)[1]
    else:
        with np.load(out, allow_pickle=False) as z:
            P = z["points"]
    missing = ~np.isfinite(P).all(axis=2)
    assert int(missing.sum()) == n_left
    assert int((seq.mask & ~missing).sum()) == n_filled
