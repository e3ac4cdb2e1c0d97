"""The embedded sample recording, so the demo and the tests run with no network and no data.

``sample_walk.c3d`` is a synthetic walking recording (41 markers, 8 s at 120 Hz, mm, Z up) made
by :func:`torchfill.data.synth.synthetic_walk` and written by torchfill itself
(``scripts/make_sample.py`` regenerates it). Real recordings may not be redistributed.
"""
from __future__ import annotations

from pathlib import Path

from ..sequence import MarkerSequence
from .synth import synthetic_walk

SAMPLE_NAME = "sample_walk.c3d"


def sample_path() -> Path:
    """Path of the shipped sample recording (a file inside the installed package)."""
    return Path(__file__).resolve().parent / SAMPLE_NAME


def load_sample() -> MarkerSequence:
    """The shipped sample, read with :func:`torchfill.read` (no gaps: simulate your own)."""
    from ..io import read

    return read(sample_path())


__all__ = ["load_sample", "sample_path", "synthetic_walk"]
