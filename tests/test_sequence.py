"""MarkerSequence: cutting frames and markers, units and axes."""
from __future__ import annotations

import numpy as np
import pytest

import torchfill
from torchfill.data import load_sample
from torchfill.sequence import MarkerSequence, parse_axes, unit_power


@pytest.fixture(scope="module")
def sample():
    seq = load_sample()
    seq.meta["filled"] = np.zeros(seq.points.shape[:2], dtype=bool)
    seq.meta["filled"][5:9, 3] = True
    return seq


def test_frames_by_slice(sample, tmp_path):
    cut = sample[:100]
    assert cut.n_frames == 100 and cut.labels == sample.labels
    np.testing.assert_array_equal(cut.points, sample.points[:100])
    assert cut.first_frame == sample.first_frame and cut.meta["filled"].shape == (100, 41)
    later = sample[200:300]
    assert later.first_frame == sample.first_frame + 200
    assert later.source is None                  # written fresh: the other frames are not kept
    torchfill.write(later, tmp_path / "cut.c3d")
    back = torchfill.read(tmp_path / "cut.c3d")
    assert back.first_frame == later.first_frame
    np.testing.assert_allclose(back.points, later.points, rtol=1e-6)
    with pytest.raises(IndexError, match="step 1"):
        sample[::2]


def test_markers_by_label(sample):
    two = sample[["LFWT", "RFWT"]]
    assert two.labels == ["LFWT", "RFWT"] and two.n_frames == sample.n_frames
    np.testing.assert_array_equal(two.points[:, 1], sample.points[:, sample.labels.index("RFWT")])
    assert sample["LFWT"].n_markers == 1
    both = sample[:100, ["LFWT", "RFWT"]]
    assert both.points.shape == (100, 2, 3)
    assert both.meta["filled"].shape == (100, 2)
    with pytest.raises(KeyError, match="did you mean 'LFWT'"):
        sample[["LFWX"]]


def test_the_reported_cuts_on_a_lab_file(recording):
    """``seq[:100]`` and ``seq[["LASI", "RASI"]]`` on a Vicon file (labels may carry a subject
    prefix: the short label is enough when it names one marker)."""
    seq = torchfill.read(recording("c3dorg_s00_vicon_cgm24_walking01.c3d"))
    assert seq[:100].n_frames == 100
    pelvis = seq[["LASI", "RASI"]]
    assert [label.rsplit(":", 1)[-1] for label in pelvis.labels] == ["LASI", "RASI"]
    assert seq[:100, ["LASI", "RASI"]].points.shape == (100, 2, 3)


def test_units_and_axes_round_trip(sample):
    m = sample.in_units("m")
    assert m.units == "m"
    np.testing.assert_allclose(m.points, sample.points / 1000.0)
    turned = sample.with_axes("zup-to-yup")
    np.testing.assert_array_equal(turned.points[..., 1], sample.points[..., 2])
    np.testing.assert_array_equal(turned.points[..., 2], -sample.points[..., 1])
    np.testing.assert_array_equal(turned.with_axes("yup-to-zup").points, sample.points)
    assert parse_axes("X, Z, -Y") == parse_axes("zup-to-yup") == ((0, 2, 1), (1, 1, -1))
    assert unit_power("mm", "m") == -3 and unit_power("m", "mm") == 3
    for bad in ("x,x,y", "x,y", "up"):
        with pytest.raises(ValueError, match="signed permutation"):
            parse_axes(bad)
    with pytest.raises(ValueError, match="units expected"):
        sample.in_units("inch")
    with pytest.raises(ValueError, match="3-D"):
        MarkerSequence(np.zeros((2, 1, 2)), ["a"]).with_axes("zup-to-yup")
