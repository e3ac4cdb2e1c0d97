"""Shared test fixtures: where the real recordings live.

The recordings are not part of the repository. They are looked up in the folder named by the
environment variable ``TORCHFILL_DATA`` or else in ``shared/data`` beside the repository
(``<repo>/../shared/data``). Tests that need them skip cleanly when the folder is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = Path(os.environ.get("TORCHFILL_DATA") or (REPO_ROOT / ".." / "shared" / "data")).resolve()


def data_files(*suffixes: str) -> list[Path]:
    """Recordings in :data:`DATA_DIR` with one of the given suffixes (empty if the folder is absent).

    Use in ``pytest.mark.parametrize``; ids come out as file names.
    """
    if not DATA_DIR.is_dir():
        return []
    wanted = {s.lower() for s in suffixes}
    return sorted(p for p in DATA_DIR.iterdir() if p.suffix.lower() in wanted)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The shared data folder; skips the test when it is absent."""
    if not DATA_DIR.is_dir():
        pytest.skip(f"shared recordings not found at {DATA_DIR} (set TORCHFILL_DATA)")
    return DATA_DIR


@pytest.fixture(scope="session")
def recording(data_dir):
    """Factory: ``recording("cmu_02_01.c3d")`` returns the path, or skips if that file is absent."""

    def _get(name: str) -> Path:
        path = data_dir / name
        if not path.is_file():
            pytest.skip(f"recording {name} not found in {data_dir}")
        return path

    return _get
