""".npy / .npz / .csv: both layouts, labels and metadata, missing cells, and the shared CSV."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import torchfill
from torchfill.sequence import MarkerSequence

from iohelpers import synthetic


@pytest.mark.parametrize("layout", ["tj3", "t3j"])
def test_npy_round_trip_both_layouts(layout, tmp_path):
    seq = synthetic()
    out = tmp_path / "a.npy"
    torchfill.write(seq, out, layout=layout)
    stored = np.load(out)
    assert stored.shape == ((60, 5, 3) if layout == "tj3" else (60, 15))
    back = torchfill.read(out, rate=120.0)
    np.testing.assert_array_equal(back.points, seq.points)
    assert back.rate == 120.0 and back.labels == [f"M{j + 1}" for j in range(5)]


def test_t3j_columns_are_x1_y1_z1_x2(tmp_path):
    """A (T, 3J) matrix is x1 y1 z1 x2 ...: marker j is columns 3j..3j+2 (not column-major)."""
    M = np.arange(2 * 6, dtype=float).reshape(2, 6)
    np.save(tmp_path / "m.npy", M)
    seq = torchfill.read(tmp_path / "m.npy")
    np.testing.assert_array_equal(seq.points[0, 1], [3.0, 4.0, 5.0])


def test_npz_keeps_labels_rate_units(tmp_path):
    seq = synthetic(units="m")
    out = tmp_path / "a.npz"
    torchfill.write(seq, out)
    back = torchfill.read(out)
    assert (back.labels, back.rate, back.units) == (seq.labels, seq.rate, "m")
    np.testing.assert_array_equal(back.points, seq.points)


def test_csv_round_trip_is_exact(tmp_path):
    seq = synthetic()
    out = tmp_path / "a.csv"
    torchfill.write(seq, out)
    lines = out.read_text().splitlines()
    assert lines[0] == "# rate=120.0; units=mm; first_frame=0"
    assert lines[1].startswith("MK0_x,MK0_y,MK0_z,MK1_x")
    assert lines[2 + 10].split(",")[3:6] == ["", "", ""]       # missing: empty cells
    back = torchfill.read(out)
    assert (back.labels, back.rate, back.units) == (seq.labels, 120.0, "mm")
    np.testing.assert_array_equal(back.points, seq.points)   # shortest round-trip decimals


def test_csv_keeps_rate_units_first_frame_and_filled(tmp_path):
    """A 50 Hz recording in metres reads back as 50 Hz, m; the filled samples come back."""
    seq = synthetic(units="m")
    seq.rate, seq.first_frame = 50.0, 7
    filled = np.zeros(seq.mask.shape, bool)
    filled[3:5, 2] = filled[4, 0] = True
    seq.meta["filled"] = filled
    for name in ("a.csv", "a.npz"):
        torchfill.write(seq, tmp_path / name)
        back = torchfill.read(tmp_path / name)
        assert (back.rate, back.units, back.first_frame) == (50.0, "m", 7)
        np.testing.assert_array_equal(back.meta["filled"], filled)
        np.testing.assert_array_equal(back.points, seq.points)
    # numpy's own text reader takes the file as it is: the comment line is skipped
    table = np.genfromtxt(tmp_path / "a.csv", delimiter=",", skip_header=2)
    np.testing.assert_array_equal(table[:, :-1].reshape(seq.points.shape), seq.points)


def test_csv_headerless_empty_cells_and_partial_samples(tmp_path):
    path = tmp_path / "raw.csv"
    path.write_text("1,2,3,4,5,6\n"
                    "1.5,,3,NaN,5,6\n"
                    ",,,,,\n"
                    "\n"
                    "2,2,3,4,5,6\n")
    seq = torchfill.read(path)
    assert seq.points.shape == (4, 2, 3) and seq.labels == ["M1", "M2"]
    np.testing.assert_array_equal(seq.mask, [[False, False], [True, True], [True, True],
                                             [False, False]])
    assert np.isnan(seq.points[1]).all()                     # a partial sample is missing whole


@pytest.mark.parametrize("header,labels", [
    ("x1,y1,z1,x2,y2,z2", ["M1", "M2"]),
    ("LASI_X,LASI_Y,LASI_Z,RASI_X,RASI_Y,RASI_Z", ["LASI", "RASI"]),
    ("LASI,,,RASI,,", ["LASI", "RASI"]),
])
def test_csv_header_styles(header, labels, tmp_path):
    path = tmp_path / "h.csv"
    path.write_text(header + "\n1,2,3,4,5,6\n7,8,9,10,11,12\n")
    assert torchfill.read(path).labels == labels


def test_shared_mogapfill_csv(recording):
    seq = torchfill.read(recording("mogapfill_gait-raw.csv"))
    assert seq.points.shape == (142, 13, 3)
    assert 100 * seq.mask.mean() == pytest.approx(5.47, abs=0.01)


def test_write_accepts_a_bare_array(tmp_path):
    X = synthetic().points
    torchfill.write(X, tmp_path / "bare.npy")
    np.testing.assert_array_equal(np.load(tmp_path / "bare.npy"), X)


@settings(max_examples=25, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(1, 4), st.just(3)),
              elements=st.one_of(st.floats(-1e6, 1e6, allow_nan=False, width=64),
                                 st.just(np.nan))))
def test_csv_and_npz_round_trip_any_values(tmp_path_factory, points):
    """Any finite values and NaN survive .csv and .npz exactly (a partial sample reads as missing)."""
    expected = points.copy()
    expected[~np.isfinite(points).all(axis=2)] = np.nan
    seq = MarkerSequence(points=points, labels=[f"L{j}" for j in range(points.shape[1])])
    folder = tmp_path_factory.mktemp("rt")
    for name in ("a.csv", "a.npz"):
        torchfill.write(seq, folder / name)
        np.testing.assert_array_equal(torchfill.read(folder / name).points, expected)
