"""OpenSim 4.6 reads every TRC torchfill writes: fresh files with gaps in the first and last
columns, write-backs after a default fill, fully filled files, C3D -> TRC conversions and files in
metres; labels, rate, units, values and missing samples agree with ``torchfill.read``."""
from __future__ import annotations

import warnings
from pathlib import Path

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


# -- OpenSim-ready output: axes, units, precision, the filled record beside the file ----------
def test_zup_c3d_to_yup_metres_trc(recording, tmp_path):
    """A lab's Z-up millimetre C3D written for OpenSim (Y-up, metres): OpenSim reads the file,
    and the inverse turn of what it holds gives the C3D's samples back at float32 precision;
    numbers have at most float32's digits, line 1 is short, the filled record lies beside it."""
    seq = torchfill.read(recording("c3dorg_s26_walking_hybrid_1_4.c3d"))
    ctx = _quiet()
    try:
        filled = torchfill.fill(seq, "linear", max_gap=int(seq.rate))
        out = tmp_path / "opensim.trc"
        torchfill.write(filled, out, axes="zup-to-yup", units="m")
    finally:
        ctx.__exit__(None, None, None)
    back = _agree(out)
    assert back.units == "m"
    np.testing.assert_array_equal(back.meta["filled"], filled.meta["filled"] & ~filled.mask)
    lab = back.with_axes("yup-to-zup").in_units("mm")
    ok = ~filled.mask
    np.testing.assert_allclose(lab.points[ok], filled.points[ok], rtol=1e-6, atol=1e-9)
    observed = ~seq.mask
    np.testing.assert_array_equal(lab.points[observed].astype(np.float32),
                                  seq.points[observed].astype(np.float32))
    lines = out.read_text().splitlines()
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\topensim.trc"
    digits = max(len(c.lstrip("-").replace(".", "").lstrip("0")) for c in lines[6].split("\t")[2:])
    assert digits <= 9
    assert (tmp_path / "opensim.trc.filled").read_text().count("\n") > 2


def test_axes_and_units_keep_a_trc_sources_digits(recording, tmp_path):
    """From a TRC with 6 decimals in mm, metres get 9 decimals: the same digits, the point moved."""
    src = recording("osim_gait2392_subject01_walk1.trc")
    seq = torchfill.read(src)
    out = tmp_path / "m.trc"
    torchfill.write(seq, out, axes="x,z,-y", units="m")
    row_in = src.read_text().splitlines()[6].split("\t")
    row_out = out.read_text().splitlines()[6].split("\t")
    assert row_out[2:5] == [_turned(row_in[2]), _turned(row_in[4]), _negated(_turned(row_in[3]))]
    back = _agree(out).with_axes("x,-z,y").in_units("mm")
    np.testing.assert_allclose(back.points, seq.points, rtol=1e-12)


def _turned(text):              # mm -> m, as text: 617.247620 -> 0.617247620
    whole, frac = text.lstrip("-").split(".")
    digits = whole.rjust(3, "0")
    out = (digits[:-3].lstrip("0") or "0") + "." + digits[-3:] + frac
    return ("-" if text.startswith("-") else "") + out


def _negated(text):
    return text[1:] if text.startswith("-") else "-" + text


@pytest.mark.slow
def test_ik_on_a_lab_c3d_turned_for_opensim_matches_the_original(data_dir, tmp_path):
    """gait2392's walk turned to a lab's Z-up C3D, then filled and written with
    ``--axes zup-to-yup --units m``: OpenSim IK gives the original file's joint angles.

    IK runs at accuracy 1e-8: at the setup's 1e-5 the solver's own tolerance moves angles by
    up to 0.08 deg between two files that differ only in the last bit of a coordinate (the same
    digits in m instead of mm), which would hide what this test checks."""
    from torchfill.cli import main

    trc = data_dir / "osim_gait2392_subject01_walk1.trc"
    setup = data_dir / "opensim" / "gait2392" / "subject01_Setup_IK.xml"
    model = data_dir / "opensim" / "gait2392" / "subject01_simbody.osim"
    if not (trc.is_file() and setup.is_file() and model.is_file()):
        pytest.skip("the gait2392 recording, model or IK setup is not in the data folder")
    seq = torchfill.read(trc)
    lab = MarkerSequence(seq.with_axes("yup-to-zup").points, seq.labels, rate=seq.rate,
                         units=seq.units)
    torchfill.write(lab, tmp_path / "lab.c3d")
    assert main(["fill", str(tmp_path / "lab.c3d"), "-o", str(tmp_path / "opensim.trc"), "-q",
                 "--axes", "zup-to-yup", "--units", "m"]) == 0
    original = _ik(trc, setup, model, seq, tmp_path / "a")
    turned = _ik(tmp_path / "opensim.trc", setup, model, seq, tmp_path / "b")
    rotational = [c for c in original.dtype.names[1:] if not c.startswith("pelvis_t")]
    worst = max(np.abs(original[c] - turned[c]).max() for c in rotational)
    assert worst <= 0.01, f"joint angles differ by up to {worst:.4f} deg"


def _ik(markers, setup, model, seq, folder):
    """OpenSim IK of a marker file: the .mot table (degrees) as a structured array."""
    opensim.Logger.setLevelString("error")
    opensim.Logger.removeFileSink()                 # no opensim.log in the working directory
    folder.mkdir()
    tool = opensim.InverseKinematicsTool(str(setup))
    model = opensim.Model(str(model))               # the tool does not own it: keep it alive
    tool.setModel(model)
    tool.set_accuracy(1e-8)
    tool.set_marker_file(str(Path(markers).resolve()))   # relative: to the setup's folder
    tool.setStartTime(0.0)
    tool.setEndTime((seq.n_frames - 1) / seq.rate)
    tool.setResultsDir(str(folder.resolve()))
    tool.set_output_motion_file(str(folder.resolve() / "ik.mot"))
    assert tool.run()
    lines = (folder / "ik.mot").read_text().splitlines()
    end = next(i for i, line in enumerate(lines) if line.strip().lower() == "endheader")
    return np.genfromtxt(lines[end + 1:], names=True, delimiter="\t")
