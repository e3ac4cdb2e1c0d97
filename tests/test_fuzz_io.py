"""A small seeded run of ``scripts/fuzz_io.py``: mutated C3D/TRC/CSV/NPZ/NPY files
through read -> fill -> write -> read must keep every rule (one-line errors, nothing written on
error, observed samples and everything else kept). The full run (>= 5000 mutants) is in the
README; this one is the regression guard."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fuzz_io.py"


def _fuzz():
    spec = importlib.util.spec_from_file_location("fuzz_io", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_seeded_fuzz_synthetic(tmp_path):
    result = _fuzz().run(240, seed=18, real=False, workdir=tmp_path)
    assert result["outcomes"].get("filled", 0) > 50        # the fill path is really exercised
    assert result["outcomes"].get("error", 0) > 50          # and so are the error paths
    assert result["violations"] == []


def test_seeded_fuzz_real_recordings(tmp_path):
    fuzz = _fuzz()
    if not fuzz.DATA.is_dir():
        pytest.skip(f"shared recordings not found at {fuzz.DATA}")
    result = fuzz.run(40, seed=19, real=True, workdir=tmp_path)
    assert result["violations"] == []
