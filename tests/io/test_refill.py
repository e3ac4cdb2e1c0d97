"""Filling a filled recording changes nothing, through every format that records which samples
a fill made (C3D residual 0, the TRC first-line record, the CSV 'filled' column, the NPZ 'filled'
array, the OpenPose 'torchfill_filled' field): the second fill keeps the first one's samples and
does not extrapolate from them, so fill(read(write(fill(x)))) is read(write(fill(x))) and writes
the same file. (.npy holds bare points: a fill written there is not known as one.)"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import torchfill
from torchfill.sequence import MarkerSequence

from iohelpers import synthetic


def _gappy(T=150, J=8) -> MarkerSequence:
    seq = synthetic(T=T, J=J, gaps=False)
    P = seq.points
    P[:50, 0] = np.nan                       # long trial-start gap: partly left unfilled
    P[-60:, J - 1] = np.nan                  # long trial-end gap
    P[70:80, 3] = np.nan                     # interior gap
    P[100:104, 5] = np.nan
    P[:3] = np.nan                           # no marker seen: never filled
    seq.first_frame = 11
    return seq


def _fill(seq, method):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torchfill.fill(seq, method)


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torchfill.read(path)


def _write(seq, path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torchfill.write(seq, path)


def _contents(path):
    if path.is_dir():
        return {p.name: p.read_bytes() for p in sorted(path.iterdir())}
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k].tobytes() + str(z[k].dtype).encode() for k in z.files}
    return path.read_bytes()


def _refill(source, tmp_path, method, suffix):
    """Fill the recording at ``source``, write it, read it, fill again, write again."""
    x = _read(source)
    f1 = _fill(x, method)
    assert f1.meta["filled"].any() and f1.mask.any()     # something filled, something left
    out1, out2 = tmp_path / f"once{suffix}", tmp_path / f"twice{suffix}"
    _write(f1, out1)
    r1 = _read(out1)
    np.testing.assert_array_equal(r1.meta["filled"], f1.meta["filled"])
    np.testing.assert_array_equal(r1.mask, f1.mask)
    f2 = _fill(r1, method)
    np.testing.assert_array_equal(f2.points, r1.points)           # bit for bit, NaN where NaN
    np.testing.assert_array_equal(f2.meta["filled"], r1.meta["filled"])
    _write(f2, out2)
    assert _contents(out2) == _contents(out1)
    return x, f1


def test_in_memory():
    x = _gappy()
    f1 = _fill(x, None)
    f2 = _fill(f1, None)
    np.testing.assert_array_equal(f2.points, f1.points)
    np.testing.assert_array_equal(f2.meta["filled"], f1.meta["filled"])
    # the remaining trial-end samples stay unfilled: a second fill does not extrapolate further
    assert f1.mask[:, 0].sum() == f2.mask[:, 0].sum() > 0


@pytest.mark.parametrize("suffix", [".c3d", ".trc", ".csv", ".npz"])
@pytest.mark.parametrize("method", ["linear", None], ids=["linear", "default"])
def test_through_fresh_files(tmp_path, suffix, method):
    """A recording written fresh, then filled and written back (or rewritten) twice."""
    src = tmp_path / f"src{suffix}"
    _write(_gappy(), src)
    x, f1 = _refill(src, tmp_path, method, suffix)
    assert x.first_frame == f1.first_frame == 11


@pytest.mark.parametrize("name", ["c3dorg_s28_type1.c3d",            # no residuals: -0.0 marks
                                  "c3dorg_s26_walking_hybrid_1_4.c3d",  # residuals: 0 marks
                                  "mogapfill_gait-raw.csv"])
def test_through_real_files(recording, tmp_path, name):
    path = recording(name)
    suffix = path.suffix
    _refill(path, tmp_path, "linear", suffix)
    if suffix == ".csv":
        return
    for other in (".trc", ".npz", ".csv"):                 # C3D -> other formats
        folder = tmp_path / other[1:]
        folder.mkdir()
        _write(_read(path), folder / f"src{other}")
        _refill(folder / f"src{other}", folder, "linear", other)


def test_through_openpose(tmp_path):
    seq = _gappy()
    xy = seq.points[:, :, :2]
    torchfill.write(xy, tmp_path / "clip")
    _refill(tmp_path / "clip", tmp_path, "linear", "")


def test_a_second_fill_keeps_the_first_and_fills_what_it_may(tmp_path):
    """Earlier fills stay as they were, also when the second fill is asked to fill everything:
    it fits only the observed samples, and what it adds next to the kept fill is its own."""
    x = _gappy()
    f1 = _fill(x, "linear")
    f2 = torchfill.fill(f1, "linear", extrapolate=None)
    kept = f1.meta["filled"]
    np.testing.assert_array_equal(f2.points[kept], f1.points[kept])
    blackout = x.mask.all(axis=1)                         # only frames with nothing seen stay
    np.testing.assert_array_equal(f2.mask, np.repeat(blackout[:, None], x.n_markers, axis=1))
    np.testing.assert_array_equal(f2.meta["filled"], x.mask & ~f2.mask)


@pytest.mark.parametrize("method", ["linear", None], ids=["linear", "default"])
def test_a_new_fill_meets_an_earlier_fill_it_borders(method):
    """A file's own fill (kept as it was) that disagrees with ours right before a gap: the new
    fill starts from the kept samples, not from where our fill of them would have been."""
    seq = synthetic(T=150, J=8, gaps=False)
    P = seq.points
    P[60:63, 2] += 30.0                              # an earlier fill, 30 mm off the motion
    P[63:90, 2] = np.nan                             # the gap after it
    seq.meta["filled"] = np.zeros(P.shape[:2], dtype=bool)
    seq.meta["filled"][60:63, 2] = True
    out = _fill(seq, method)
    np.testing.assert_array_equal(out.points[60:63, 2], P[60:63, 2])
    steps = np.linalg.norm(np.diff(out.points[:, 2], axis=0), axis=1)
    observed = np.delete(steps, np.s_[58:91])                 # steps of the untouched motion
    assert steps[62] < 2 * observed.max()            # kept -> new: no 30 mm step
    assert steps[89] < 2 * observed.max()            # new -> observed: still continuous
