"""A small seeded run of the fuzz suite (``python -m benchmarks fuzz``): mutated C3D/TRC/CSV/NPZ/NPY files
through read -> fill -> write -> read must keep every rule (one-line errors, nothing written on
error, observed samples and everything else kept). The full run (>= 5000 mutants) is in the
README; this one is the regression guard."""
from __future__ import annotations

import pytest


def _fuzz():
    from benchmarks.suites import fuzz

    return fuzz


@pytest.mark.slow                    # benchmark-sized: a full fuzz round
def test_seeded_fuzz_synthetic(tmp_path):
    result = _fuzz().run(240, seed=18, real=False, workdir=tmp_path)
    assert result["outcomes"].get("filled", 0) > 50        # the fill path is really exercised
    assert result["outcomes"].get("error", 0) > 50          # and so are the error paths
    assert result["violations"] == []


@pytest.mark.slow                    # reads the recordings
def test_seeded_fuzz_real_recordings(tmp_path):
    fuzz = _fuzz()
    if not fuzz.data.folder().is_dir():
        pytest.skip(f"shared recordings not found at {fuzz.data.folder()}")
    result = fuzz.run(40, seed=19, real=True, workdir=tmp_path)
    assert result["violations"] == []
