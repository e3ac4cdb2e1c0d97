"""Methods behind one call: ``run(name, seq)`` -> a :class:`Filled` (points, std or None, timing).
Names: ``default`` (``torchfill.fill``'s default with its error estimate), any torchfill method,
or ``peer:NAME`` (:mod:`benchmarks.peers`). Every fill fills every hidden sample it can
(``extrapolate=None``)."""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

import torchfill

from . import peers
from .timing import Timing, measure

DEFAULT = "default"
#: The single methods the real-gap tables compare the default with.
SINGLES = ("linear", "pchip", "spline", "pma", "lgrnn", "pca_gloersen", "li", "glr", "svt",
           "tucker_tnn", "rigid")


@dataclass
class Filled:
    points: np.ndarray                  # (T, J, 3), NaN where the method filled nothing
    std: np.ndarray | None
    timing: Timing
    error: str = ""


def is_peer(name: str) -> bool:
    return name.startswith("peer:")


def available(name: str) -> bool:
    return peers.available(name[5:]) if is_peer(name) else True


def run(name: str, seq: torchfill.MarkerSequence, seed: int = 0, **kwargs) -> Filled:
    """Fill ``seq`` with method ``name``, timed; a method's ValueError (a peer's any exception)
    becomes ``error``."""
    std = None
    with measure() as t, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            if is_peer(name):
                F = peers.fill(name[5:], seq)
            elif name == DEFAULT:
                out, std = torchfill.fill(seq, extrapolate=None, return_std=True,
                                          params={"seed": seed}, **kwargs)
                F = out.points
            else:
                F = torchfill.fill(seq, method=name, extrapolate=None, **kwargs).points
        except Exception as err:                        # noqa: BLE001 - a peer's own failure
            if not (is_peer(name) or isinstance(err, ValueError)):
                raise
            return Filled(np.full_like(seq.points, np.nan), None, Timing(), str(err))
    return Filled(np.asarray(F, dtype=np.float64), std, t)


def spatial(name: str) -> bool:
    """Whether the method places markers from the same frame (the QC's spatial support)."""
    from torchfill.solvers import base

    return bool(getattr(base._REGISTRY.get(name), "spatial", False))
