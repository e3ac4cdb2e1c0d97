"""OpenSim 4.6 reads every TRC torchfill writes: fresh files with gaps in the first and last
columns, write-backs after a default fill, fully filled files, C3D -> TRC conversions and files in
metres; labels, rate, units, values and missing samples agree with ``torchfill.read``."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import torchfill
from torchfill.sequence import MarkerSequence

from iohelpers import synthetic

opensim = pytest.importorskip("opensim", reason="opensim (the dev extra) is not installed")


def _opensim(path):
    """(labels, rate, units, points (T, J, 3) with NaN) as OpenSim's TRCFileAdapter reads them."""
    table = opensim.TimeSeriesTableVec3(str(path))
    labels = list(table.getColumnLabels())
    flat = table.flatten()                # kept alive while its matrix view is read
    matrix = flat.getMatrix()
    points = np.array(matrix.to_numpy(), dtype=np.float64).reshape(table.getNumRows(),
                                                                   len(labels), 3)
    return (labels, float(table.getTableMetaDataAsString("DataRate")),
            table.getTableMetaDataAsString("Units"), points)


def _agree(path, decimals: int | None = None):
    """OpenSim and torchfill read the same file the same way."""
    seq = torchfill.read(path)
    labels, rate, units, points = _opensim(path)
    assert labels == seq.labels
    assert rate == pytest.approx(seq.rate, rel=1e-12) and units == seq.units
    assert points.shape == seq.points.shape
    ours = ~np.isfinite(seq.points).all(axis=2)
    theirs = ~np.isfinite(points).all(axis=2) | (points == 0).all(axis=2)
    np.testing.assert_array_equal(theirs, ours)
    ok = ~ours
    np.testing.assert_allclose(points[ok], seq.points[ok], rtol=1e-12, atol=1e-9)
    _agree_pose2sim(path, seq)
    return seq


def _agree_pose2sim(path, seq):
    """Pose2Sim's reader: pandas under the X1 Y1 Z1 line, 'Unnamed' columns dropped, labels
    from every third cell of line 4."""
    pd = pytest.importorskip("pandas")
    with open(path, encoding="utf-8") as handle:
        header = [next(handle) for _ in range(5)]
    labels = [m.strip() for m in header[3].split("\t")[2::3] if m.strip()]
    df = pd.read_csv(path, sep="\t", skiprows=4, encoding="utf-8")
    frames = df.iloc[:, 0].to_numpy()
    coords = df.drop(df.columns[[0, 1]], axis=1)
    coords = coords.loc[:, ~coords.columns.str.startswith("Unnamed")]
    assert labels == seq.labels
    np.testing.assert_array_equal(frames, seq.first_frame + np.arange(seq.n_frames))
    values = coords.to_numpy(dtype=np.float64).reshape(seq.points.shape)
    values[(values == 0).all(axis=2)] = np.nan
    np.testing.assert_allclose(values, seq.points, rtol=1e-12, atol=1e-9)


def _quiet():
    ctx = warnings.catch_warnings()
    ctx.__enter__()
    warnings.simplefilter("ignore")
    return ctx


def _gappy(T=120, J=6, units="mm") -> MarkerSequence:
    seq = synthetic(T=T, J=J, units=units, gaps=False)
    P = seq.points
    P[:15, 0] = np.nan                    # the first column missing at the start
    P[-40:, -1] = np.nan                  # the last marker leaves early (rows end in empty cells)
    P[50:60, -1] = np.nan
    P[70:75, 0] = np.nan
    P[90, :] = np.nan                     # a frame with nothing observed
    return seq


def test_fresh_trc_with_gaps_in_first_and_last_columns(tmp_path):
    out = tmp_path / "fresh.trc"
    torchfill.write(_gappy(), out)
    seq = _agree(out)
    assert seq.mask[-1, -1] and seq.mask[0, 0] and seq.mask[90].all()


def test_metres(tmp_path):
    out = tmp_path / "metres.trc"
    seq = _gappy(units="m")
    seq.points = seq.points / 1000.0
    torchfill.write(seq, out)
    assert _agree(out).units == "m"


@pytest.mark.parametrize("extrapolate", [0.25, None], ids=["default", "everything"])
def test_write_back_after_fill(tmp_path, extrapolate):
    src = tmp_path / "gaps.trc"
    torchfill.write(_gappy(), src)
    ctx = _quiet()
    try:
        filled = torchfill.fill(torchfill.read(src), extrapolate=extrapolate)
    finally:
        ctx.__exit__(None, None, None)
    out = tmp_path / "filled.trc"
    torchfill.write(filled, out)
    seq = _agree(out)
    if extrapolate is None:
        assert not seq.mask[:, :-1].any() or seq.mask[90].all()
    else:       # five markers seen in those frames: a spatial fill, not cut by the time limit
        assert not seq.mask[-1, -1]


def test_real_trc_repro_last_marker_leaves_early(recording, tmp_path):
    """The reported case: the last marker missing in the last 30 rows, default fill, write-back."""
    s = torchfill.read(recording("osim_gait2392_subject01_walk1.trc"))
    P = s.points.copy()
    P[-30:, -1] = np.nan
    g = tmp_path / "g.trc"
    torchfill.write(MarkerSequence(points=P, labels=s.labels, rate=s.rate, units=s.units), g)
    _agree(g)
    ctx = _quiet()
    try:
        filled = torchfill.fill(torchfill.read(g))
    finally:
        ctx.__exit__(None, None, None)
    f = tmp_path / "f.trc"
    torchfill.write(filled, f)
    _agree(f)
    # the source file's rows, written back without a fill, load too (short rows padded)
    src = torchfill.read(recording("osim_hamner_subject02_running.trc"))
    torchfill.write(src, tmp_path / "hamner.trc")
    _agree(tmp_path / "hamner.trc")


@pytest.mark.parametrize("name", ["c3dorg_s26_walking_hybrid_1_4.c3d", "ktk_tennis_serve_nan.c3d",
                                  "cmu_02_01.c3d"])
def test_c3d_to_trc(recording, tmp_path, name):
    seq = torchfill.read(recording(name))
    out = tmp_path / (name[:-4] + ".trc")
    ctx = _quiet()
    try:
        torchfill.write(seq, out)
        _agree(out)
        filled = torchfill.fill(seq, "linear", max_gap=int(seq.rate))
        torchfill.write(filled, tmp_path / "filled.trc")
    finally:
        ctx.__exit__(None, None, None)
    back = _agree(tmp_path / "filled.trc")
    assert back.first_frame == seq.first_frame
    np.testing.assert_array_equal(back.mask, filled.mask)
