"""The embedded sample recording, so the demo and the tests run with no network and no data.

``sample_walk.c3d`` is a synthetic walking recording (41 markers, 8 s at 120 Hz, mm, Z up) made
by :func:`torchfill.data.synth.synthetic_walk` and written by torchfill itself
(``scripts/make_sample.py`` regenerates it). Real recordings may not be redistributed.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..sequence import MarkerSequence
from .synth import synthetic_walk

SAMPLE_NAME = "sample_walk.c3d"


def sample_path() -> Path:
    """Path of the shipped sample recording (a file inside the installed package)."""
    return Path(__file__).resolve().parent / SAMPLE_NAME


def data_dir(beside: str | Path | None = None) -> Path:
    """The folder of the real recordings used for development (not shipped): ``$TORCHFILL_DATA``,
    or else ``shared/data`` beside the checkout ``beside`` (default: the working directory), i.e.
    ``<beside>/../shared/data``. The folder may be absent: callers skip or say so."""
    env = os.environ.get("TORCHFILL_DATA")
    if env:
        return Path(env).resolve()
    return (Path(beside) if beside is not None else Path.cwd()).resolve().parent / "shared" / "data"


def load_sample() -> MarkerSequence:
    """The shipped sample, read with :func:`torchfill.read` (no gaps: simulate your own)."""
    from ..io import read

    return read(sample_path())


__all__ = ["data_dir", "load_sample", "sample_path", "synthetic_walk"]
