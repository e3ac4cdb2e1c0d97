"""The fill's per-gap verdicts recorded in a written C3D (the TORCHFILL parameter group): they
read back as written, every fill (kept rejected ones too) stays a valid sample for other readers,
and observed samples keep their bytes."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import torchfill
from torchfill import batch, qc
from torchfill.io import c3d as tc3d
from torchfill.io import c3d_marks

from iohelpers import synthetic
from test_c3d import _convert


def _default_fill(seq):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, _ = torchfill.fill(seq, return_std=True)
    rows = batch.mark_verdicts(seq, out, None, "auto")
    return out, rows


def _ezc3d(path, labels):
    """ezc3d's points (T, J, 3) of ``labels`` (NaN where it reads a sample as invalid) and
    residuals (T, J): OpenSim's C3D reader is built on ezc3d."""
    ezc3d = pytest.importorskip("ezc3d")
    c = ezc3d.c3d(str(path))
    names = list(c["parameters"]["POINT"]["LABELS"]["value"])
    idx = [names.index(label) for label in labels]
    xyz = np.asarray(c["data"]["points"][:3, idx], dtype=np.float64).transpose(2, 1, 0)
    return xyz, c["data"]["meta_points"]["residuals"][0, idx].T, c


def test_verdict_names_are_the_qc_verdicts():
    assert c3d_marks.VERDICT_NAMES == qc.VERDICTS


@pytest.mark.parametrize("name", ["c3dorg_s04_sub_labels.c3d",
                                  pytest.param("c3dorg_s26_walking_hybrid_1_2.c3d",
                                               marks=pytest.mark.slow)])
def test_kept_rejected_fills_are_marked_in_the_file_and_read_as_data(name, recording, tmp_path):
    """Write-back of the default's fill with its verdicts: read back, each filled sample carries
    its gap's verdict; ezc3d (OpenSim's reader) and the c3d package read every fill, rejected
    ones too, as a valid sample with residual 0 and see the TORCHFILL group; observed samples
    and the analog data are unchanged."""
    path = recording(name)
    seq = torchfill.read(path)
    out, rows = _default_fill(seq)
    assert {r["verdict"] for r in rows if r["filled_frames"]} >= {"check", "reject"}
    target = tmp_path / name
    torchfill.write(out, target)
    back = torchfill.read(target)
    written = np.isfinite(back.points).all(axis=2)  # a fill int16 cannot hold stays missing
    expected = qc.sample_verdicts(rows, out.points)
    np.testing.assert_array_equal(back.meta["verdict"], np.where(written, expected, -1))
    for r in rows:                                  # the file's marks are the verdicts
        fin = written[r["start"]:r["stop"], r["j"]] & (r["filled_frames"] > 0)
        codes = back.meta["verdict"][r["start"]:r["stop"], r["j"]]
        assert (codes[fin] == qc.VERDICTS.index(r["verdict"])).all() and (codes[~fin] == -1).all()
    observed = ~seq.mask
    assert np.array_equal(back.points[observed], seq.points[observed])
    xyz, residual, c = _ezc3d(target, seq.labels)
    fills = back.meta["verdict"] >= 0
    assert np.isfinite(xyz[fills]).all() and (residual[fills] == 0).all()
    assert np.isfinite(xyz[back.meta["verdict"] == 2]).all()
    assert np.isnan(xyz[back.mask]).all()
    assert list(c["parameters"]["TORCHFILL"]["VERDICTS"]["value"]) == list(qc.VERDICTS)
    ref = pytest.importorskip("ezc3d").c3d(str(path))
    np.testing.assert_array_equal(c["data"]["analogs"], ref["data"]["analogs"])
    raw = tc3d.read_raw(target)
    cols = np.asarray(seq.meta["point_index"])
    assert (raw.residual[:, cols][fills] == 0).all()


def _codes(seq, rng):
    """Verdict codes on the filled samples of ``seq`` (gaps filled linearly), one per gap."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq, "linear", extrapolate=None)
    codes = np.full(seq.mask.shape, -1, dtype=np.int8)
    for j in range(seq.n_markers):
        m = np.r_[False, out.meta["filled"][:, j], False]
        edges = np.flatnonzero(np.diff(m.astype(int)))
        for a, b in zip(edges[::2], edges[1::2]):
            codes[a:b, j] = rng.integers(0, 3)
    out.meta["verdict"] = codes
    return out, codes


@pytest.mark.parametrize("processor", ["intel", "mips", "dec"])
def test_marks_round_trip_fresh_and_other_processors(processor, tmp_path):
    seq = synthetic()
    fresh = tmp_path / "fresh.c3d"
    out, codes = _codes(seq, np.random.default_rng(1))
    torchfill.write(out, fresh)
    np.testing.assert_array_equal(torchfill.read(fresh).meta["verdict"], codes)
    if processor == "intel":
        return
    other = tmp_path / f"{processor}.c3d"
    plain = tmp_path / "plain.c3d"
    torchfill.write(seq, plain)
    other.write_bytes(_convert(plain.read_bytes(), processor))
    src = torchfill.read(other)
    filled, codes = _codes(src, np.random.default_rng(2))
    target = tmp_path / f"{processor}_filled.c3d"
    torchfill.write(filled, target)
    back = torchfill.read(target)
    np.testing.assert_array_equal(back.meta["verdict"], codes)
    np.testing.assert_array_equal(back.points, filled.points.astype(np.float32))


def test_many_runs_grow_the_parameter_section_and_a_rewrite_replaces_the_group(recording,
                                                                              tmp_path):
    """More runs than one parameter holds (GAPS, GAPS2, ...) in a file whose data follows its
    parameters at once: the data block moves, every reader still finds it; writing the read-back
    file again with other verdicts leaves one TORCHFILL group holding the new ones."""
    path = recording("c3dorg_s26_walking_hybrid_1_1.c3d")
    seq = torchfill.read(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(seq, "linear", extrapolate=None)
    codes = np.where(out.meta["filled"], (np.arange(seq.n_frames) % 3)[:, None], -1)
    out.meta["verdict"] = codes.astype(np.int8)
    target = tmp_path / "many.c3d"
    torchfill.write(out, target)
    lay = tc3d.parse(target.read_bytes(), target)
    assert lay.get("TORCHFILL:GAPS3") is not None
    assert lay.data_offset > tc3d.parse(path.read_bytes(), path).data_offset
    back = torchfill.read(target)
    np.testing.assert_array_equal(back.meta["verdict"], codes)
    np.testing.assert_array_equal(back.points[~seq.mask], seq.points[~seq.mask])
    xyz, _, c = _ezc3d(target, seq.labels)
    np.testing.assert_array_equal(np.isnan(xyz).any(axis=2), back.mask)
    again = back.with_points(back.points)
    again.meta["verdict"] = np.where(codes >= 0, 1, -1).astype(np.int8)
    second = tmp_path / "again.c3d"
    torchfill.write(again, second)
    lay2 = tc3d.parse(second.read_bytes(), second)
    assert lay2.get("TORCHFILL:GAPS2") is None
    np.testing.assert_array_equal(torchfill.read(second).meta["verdict"],
                                  again.meta["verdict"])
    assert len([g for g in lay2.params if g == "TORCHFILL"]) == 1


def test_a_write_without_verdicts_keeps_the_source_bytes(recording, tmp_path):
    path = recording("c3dorg_s02_pc_real.c3d")
    seq = torchfill.read(path)
    target = tmp_path / "same.c3d"
    torchfill.write(seq, target)
    assert target.read_bytes() == path.read_bytes()
