"""Shared test fixtures: where the real recordings live.

The recordings are not part of the repository. They are looked up in the folder named by the
environment variable ``TORCHFILL_DATA`` or else in ``shared/data`` beside the repository
(``<repo>/../shared/data``). Tests that need them skip cleanly when the folder is absent.

Test modules should use the fixtures, not ``import conftest``: pytest swaps the ``conftest`` module
between test folders (tests/lightning has its own), so such an import breaks depending on the
collection order. To parametrize over the shared files, compute the folder the same way in a
helper module of your own (see ``tests/io/iohelpers.py``).
"""
from __future__ import annotations

from pathlib import Path

import pytest

from torchfill.data import data_dir

REPO_ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = data_dir(REPO_ROOT)


@pytest.fixture(autouse=True)
def _thread_settings():
    """Each test ends with torch's thread count and ``OMP_NUM_THREADS`` as it began: the CLI run
    in-process sets both from the machine's load (``torchfill.cli``), which would leave the tests
    after it on another count (and so on other last bits) than when run alone."""
    import os

    import torch

    threads, env = torch.get_num_threads(), os.environ.get("OMP_NUM_THREADS")
    yield
    if os.environ.get("OMP_NUM_THREADS") != env:
        os.environ.pop("OMP_NUM_THREADS", None) if env is None else os.environ.update(
            OMP_NUM_THREADS=env)
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


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


@pytest.fixture(scope="session")
def walk():
    """Factory: ``walk(T, J, seed)`` a smooth synthetic marker motion ``(T, J, 3)`` in mm, for
    tests that need a small complete recording to cut gaps into."""

    def _make(T: int = 150, J: int = 6, seed: int = 0):
        import numpy as np

        rng = np.random.default_rng(seed)
        t = np.linspace(0, 3, T)[:, None, None]
        phase = rng.uniform(0, 2 * np.pi, size=(1, J, 3))
        return 500 + 100 * np.sin(2 * np.pi * t + phase) + 30 * np.cos(5 * t + phase)

    return _make


@pytest.fixture(scope="session")
def gappy_sample(tmp_path_factory):
    """The embedded sample with 10 markers' simulated gaps (``gaps.multi_gap``, 60 frames, up to
    3 each, seed 1), written as a fresh C3D: a small gapped file for CLI and docs tests."""
    import numpy as np

    import torchfill
    from torchfill import gaps

    seq = torchfill.read(torchfill.data.sample_path())
    mask = gaps.multi_gap(seq.n_frames, seq.n_markers, n_markers=10, gap_length=60, max_gaps=3,
                          seed=1)
    out = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
    out.source = None
    path = tmp_path_factory.mktemp("sample") / "trial.c3d"
    torchfill.write(out, path)
    return path


def _reads_the_recordings(item) -> bool:
    """Whether a test reads the shared recordings: through the ``data_dir`` or ``recording``
    fixtures (directly or through another fixture), or parametrized with a file from there."""
    if {"data_dir", "recording"} & set(getattr(item, "fixturenames", ())):
        return True
    params = getattr(getattr(item, "callspec", None), "params", {})
    return any(isinstance(v, Path) and DATA_DIR in v.parents for v in params.values())


def pytest_collection_modifyitems(config, items):
    """Tests on the real recordings are ``slow``: ``pytest -m "not slow"`` is the fast inner loop
    on synthetic data (every module still runs), the full suite (CI) runs them all."""
    for item in items:
        if _reads_the_recordings(item):
            item.add_marker(pytest.mark.slow)
