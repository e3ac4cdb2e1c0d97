"""Where the recordings are read from, and reading them the way every suite does.

The recordings are not redistributed: ``--data DIR``, ``$TORCHFILL_DATA`` or ``shared/data``
beside the checkout (:func:`torchfill.data.data_dir`)."""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill.data import data_dir

#: The repository (results and docs are written under it).
REPO = Path(__file__).resolve().parents[1]
#: Per-suite result rows and tables.
RESULTS = REPO / "experiments" / "results"
DOCS = REPO / "docs"


def folder() -> Path:
    """The data folder (``--data`` sets ``$TORCHFILL_DATA`` before any suite runs)."""
    return data_dir(REPO)


def set_folder(path: str | Path | None) -> None:
    if path:
        os.environ["TORCHFILL_DATA"] = str(Path(path).resolve())


def need(*names: str) -> Path:
    """The data folder, or a one-line exit naming what is missing."""
    root = folder()
    missing = [n for n in names if not (root / n).exists()] if root.is_dir() else [str(root)]
    if missing:
        raise SystemExit(f"benchmarks: {root}: missing {', '.join(missing)} (point --data or "
                         "TORCHFILL_DATA at the recordings)")
    return root


def read(path: Path) -> torchfill.MarkerSequence:
    """A recording, its reader's warnings silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torchfill.read(path)


def in_mm(seq: torchfill.MarkerSequence) -> torchfill.MarkerSequence:
    scale = {"m": 1000.0, "cm": 10.0, "mm": 1.0}.get(seq.units.strip().lower(), 1.0)
    out = seq.with_points(seq.points * scale)
    out.units = "mm"
    return out


def complete(path: Path) -> torchfill.MarkerSequence:
    """The recording's markers that are never missing (unlabeled ``*`` copies dropped), in mm."""
    seq = in_mm(read(path))
    keep = [j for j, lab in enumerate(seq.labels)
            if not lab.startswith("*") and np.isfinite(seq.points[:, j]).all()]
    return seq.select(keep)
