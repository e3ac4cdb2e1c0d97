"""Round trips to the ecosystem's data types keep values (NaN too), labels, rate and units."""
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill import MarkerSequence


def _gappy(d: int = 3) -> MarkerSequence:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 4, d)) * 100.0
    points[5:12, 1] = np.nan                       # a gap
    points[0, 3] = np.nan                          # a sample at the start
    return MarkerSequence(points, ["Subj:LASI", "RASI", "LKNE", "R KNE"], rate=150.0, units="m")


def _same(a: MarkerSequence, b: MarkerSequence) -> None:
    assert np.array_equal(a.points, b.points, equal_nan=True)
    assert a.labels == b.labels and a.rate == b.rate and a.units == b.units


@pytest.mark.parametrize("d", [3, 2])
def test_pandas_round_trip(d):
    pytest.importorskip("pandas")
    seq = _gappy(d)
    df = seq.to_pandas()
    assert df.shape == (50, 4 * d)
    assert list(df.columns.names) == ["marker", "axis"]
    assert df.index.name == "time" and df.index[1] == pytest.approx(1 / 150)
    assert df[("RASI", "y")].iloc[6] != df[("RASI", "y")].iloc[6]          # NaN in the gap
    assert df[("LKNE", "x")].iloc[7] == seq.points[7, 2, 0]
    _same(seq, MarkerSequence.from_pandas(df))
    plain = df.copy()
    plain.attrs = {}                                # rate from the time index; units given
    _same(seq, MarkerSequence.from_pandas(plain, units="m"))


def test_pandas_rejects_flat_columns():
    pd = pytest.importorskip("pandas")
    with pytest.raises(ValueError, match="MultiIndex"):
        MarkerSequence.from_pandas(pd.DataFrame(np.zeros((3, 3))))


def test_xarray_round_trip():
    pytest.importorskip("xarray")
    seq = _gappy()
    da = seq.to_xarray()
    assert da.dims == ("time", "marker", "axis")
    assert list(da["marker"].values) == seq.labels
    assert float(da.sel(marker="LKNE", axis="z")[3]) == seq.points[3, 2, 2]
    _same(seq, MarkerSequence.from_xarray(da))
    _same(seq, MarkerSequence.from_xarray(da.transpose("marker", "axis", "time")))


def test_ktk_round_trip():
    pytest.importorskip("kineticstoolkit")
    seq = _gappy()
    ts = seq.to_ktk()
    assert list(ts.data) == seq.labels
    assert ts.data["RASI"].shape == (50, 4)
    assert np.isnan(ts.data["RASI"][5:12]).all()                       # the whole row, as ktk does
    assert (ts.data["LKNE"][:, 3] == 1).all()
    assert ts.info["LKNE"]["Unit"] == "m"
    _same(seq, MarkerSequence.from_ktk(ts))


def test_ktk_refuses_what_it_cannot_hold():
    pytest.importorskip("kineticstoolkit")
    with pytest.raises(ValueError, match="3-D"):
        _gappy(2).to_ktk()
    seq = _gappy()
    seq.labels[1] = seq.labels[0]
    with pytest.raises(ValueError, match="duplicate"):
        seq.to_ktk()


def test_ktk_reads_a_c3d_like_torchfill(tmp_path):
    """ktk's own C3D reader and torchfill's give the same markers once through from_ktk."""
    ktk = pytest.importorskip("kineticstoolkit")
    pytest.importorskip("ezc3d")
    path = torchfill.data.sample_path()
    ours = torchfill.read(path)
    theirs = MarkerSequence.from_ktk(ktk.read_c3d(str(path), convert_point_unit=False)["Points"])
    common = [label for label in ours.labels if label in theirs.labels]
    assert len(common) == ours.n_markers
    a = ours.select(common).points
    b = theirs.select(common).points
    assert theirs.rate == pytest.approx(ours.rate)
    assert np.allclose(a, b, atol=1e-3 * np.nanmax(np.abs(a)), equal_nan=True)


@pytest.mark.filterwarnings("ignore:.*extrapolated")
def test_fill_through_pandas():
    """A DataFrame in, filled, back to a DataFrame: observed cells unchanged."""
    pytest.importorskip("pandas")
    seq = _gappy()
    df = seq.to_pandas()
    out = torchfill.fill(MarkerSequence.from_pandas(df), "linear").to_pandas()
    seen = df.notna().to_numpy()
    assert np.array_equal(out.to_numpy()[seen], df.to_numpy()[seen])
    assert out.notna().to_numpy().all()


def _opensim_trc(path):
    """A small reader of the TRC layout as OpenSim's TRCFileAdapter and Pose2Sim expect it,
    independent of torchfill.io: line 1 ``PathFileType 4 (X/Y/Z) name``; line 2 the header keys,
    line 3 their values; line 4 ``Frame# Time`` and one label every third column; line 5
    ``X1 Y1 Z1 ...``; then (after an optional blank line) one tab-separated row per frame, an empty
    cell for a missing coordinate."""
    lines = Path(path).read_text().split("\n")
    assert lines[0].split("\t")[:2] == ["PathFileType", "4"]
    header = dict(zip(lines[1].split("\t"), lines[2].split("\t")))
    n_frames, n_markers = int(header["NumFrames"]), int(header["NumMarkers"])
    names = lines[3].split("\t")
    assert names[:2] == ["Frame#", "Time"]
    labels = [names[2 + 3 * j] for j in range(n_markers)]
    assert all(n == "" for j in range(n_markers) for n in names[3 + 3 * j: 5 + 3 * j])
    axes = lines[4].split("\t")[2: 2 + 3 * n_markers]
    assert axes == [f"{a}{j + 1}" for j in range(n_markers) for a in "XYZ"]
    rows = [line.split("\t") for line in lines[5:] if line.strip()]
    assert len(rows) == n_frames
    values = np.array([[float(c) if c.strip() else np.nan for c in r[2: 2 + 3 * n_markers]]
                       + [np.nan] * (2 + 3 * n_markers - len(r)) for r in rows])
    time = np.array([float(r[1]) for r in rows])
    return (values.reshape(n_frames, n_markers, 3), labels, float(header["DataRate"]),
            header["Units"], time)


def test_trc_as_opensim_reads_it(tmp_path):
    """A TRC written by torchfill (fresh, with gaps) reads back through the OpenSim layout with
    its labels, rate, units, time column and values, missing samples as empty cells."""
    seq = _gappy()
    seq.units = "mm"
    path = tmp_path / "walk.trc"
    torchfill.write(seq, path)
    points, labels, rate, units, time = _opensim_trc(path)
    assert labels == seq.labels and rate == seq.rate and units == "mm"
    assert np.allclose(time, np.arange(seq.n_frames) / seq.rate, atol=1e-6)
    assert np.array_equal(np.isnan(points), np.isnan(seq.points))
    assert np.allclose(points, seq.points, rtol=1e-6, equal_nan=True)


def test_opensim_layout_reader_agrees_on_an_opensim_file(recording):
    """The layout reader above reads OpenSim's own example TRC as torchfill does (so the check
    of torchfill's TRC is made with a reader that OpenSim's files satisfy)."""
    path = recording("osim_gait2392_subject01_walk1.trc")
    points, labels, rate, units, _ = _opensim_trc(path)
    seq = torchfill.read(path)
    assert labels == seq.labels and rate == seq.rate and units == seq.units
    assert np.allclose(points, seq.points, equal_nan=True)
