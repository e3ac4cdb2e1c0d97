"""The IK benchmark's own machinery (``benchmarks/suites/ik.py``) on one tiny case: OpenSim IK on the
complete recording reproduces itself, and a gapped and a filled recording both give finite joint
angles for every frame. Skips without opensim or the OpenSim models in the data folder."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import torchfill



@pytest.fixture(scope="module")
def bench():
    pytest.importorskip("opensim")
    from benchmarks import data
    from benchmarks.suites import ik

    rec = ik.RECORDINGS["gait2392"]
    for name in (rec.trc, rec.model, rec.setup):
        if not (data.folder() / name).is_file():
            pytest.skip(f"{name} not found in {data.folder()}")
    return ik


@pytest.fixture(scope="module")
def tiny(bench):
    """30 frames of the walking trial, where a real gap mask laid onto it has the most gaps."""
    rec = bench.RECORDINGS["gait2392"]
    full = bench.load_recording(rec)
    recording, source, seed = bench.CASES[0]
    used = bench.ik_markers(rec)
    mask = bench.transplant_mask(torchfill.read(bench.data.folder() / source), full, seed, used)
    assert not mask[:, [j for j, lab in enumerate(full.labels) if lab not in used]].any()
    counts = np.convolve(mask.sum(axis=1), np.ones(30), mode="valid")
    start = int(counts.argmax())
    rec = replace(rec, frames=(start, start + 30))
    return rec, bench.load_recording(rec), mask[start:start + 30]


def test_transplanted_mask_is_a_real_partial_mask(tiny):
    _, seq, mask = tiny
    assert mask.shape == (seq.n_frames, seq.n_markers)
    assert mask.any()
    assert (~mask).any(axis=1).all()            # no frame loses every marker


def test_ik_reproduces_itself_and_filled_angles_are_finite(bench, tiny, tmp_path):
    rec, seq, mask = tiny
    free = bench.free_rotations(rec)
    assert {"hip_flexion_r", "knee_angle_l", "ankle_angle_r", "pelvis_tilt"} <= set(free)
    assert "pelvis_tx" not in free and "mtp_angle_r" not in free    # translation; coordinate task
    ref = bench.run_ik(rec, seq, tmp_path / "ref")
    again = bench.run_ik(rec, seq, tmp_path / "again")
    gap_frames = mask.any(axis=1)
    same = bench.score(ref, again, free, gap_frames)
    assert same["rmse_all"] == 0.0 and same["max_err"] == 0.0
    assert np.isfinite(ref.angles).all() and ref.angles.shape[0] == seq.n_frames

    gapped = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
    for method in ("gaps", "pchip"):
        out, _ = bench.fill_case(gapped, method)
        got = bench.run_ik(rec, out, tmp_path / method)
        assert got.angles.shape == ref.angles.shape
        assert np.isfinite(got.angles).all()
        row = bench.score(ref, got, free, gap_frames)
        assert np.isfinite(row["rmse_all"]) and row["rmse_all"] > 0.0    # the gaps changed IK
        assert np.isfinite(row["marker_rms_mm"])
