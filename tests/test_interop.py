"""Round trips to the ecosystem's data types keep values (NaN too), labels, rate and units."""
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
