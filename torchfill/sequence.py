"""The one in-memory form of a recording: :class:`MarkerSequence`."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np


@dataclass
class MarkerSequence:
    """A marker recording: ``points`` of shape ``(T, J, D)`` (frames x markers x coordinates).

    ``D`` is 3 for marker data (xyz) and 2 for image keypoints (xy, e.g. OpenPose). Missing samples
    are ``NaN`` in all coordinates.

    Attributes
    ----------
    points : ndarray, float64, shape (T, J, D), D = 2 or 3
    labels : list of str, length J (prefixes such as ``Subject:`` are kept; see :meth:`short_labels`)
    rate : float
        Frames per second.
    units : str
        Length unit of ``points`` ("mm" or "m", as stored in the file).
    source : Path or None
        The file this sequence was read from; writers use it to keep everything else in the file.
    meta : dict
        Reader-specific extras (e.g. the C3D point indices the markers came from). ``filled``
        (T, J) bool marks samples a fill made (set by :func:`torchfill.fill`, and by the readers
        from the file's own mark: C3D residual 0, the TRC/CSV/NPZ/OpenPose records torchfill
        writes); ``fill()`` keeps such samples as they are but does not fit to them.
    first_frame : int
        The file's number of the first frame (C3D first frame, TRC ``Frame#`` of the first row;
        0 for arrays): frame ``t`` of ``points`` is the file's frame ``first_frame + t``.
    """

    points: np.ndarray
    labels: list[str]
    rate: float = 100.0
    units: str = "mm"
    source: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    first_frame: int = 0

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64)
        if self.points.ndim != 3 or self.points.shape[2] not in (2, 3):
            raise ValueError(f"points must have shape (T, J, 3) or (T, J, 2), found "
                             f"{self.points.shape}")
        self.labels = [str(label) for label in self.labels]
        if isinstance(self.first_frame, bool) or not isinstance(self.first_frame,
                                                                (int, np.integer)):
            raise ValueError(f"first_frame must be an int, found {self.first_frame!r}")
        self.first_frame = int(self.first_frame)
        if len(self.labels) != self.points.shape[1]:
            raise ValueError(
                f"expected {self.points.shape[1]} labels (one per marker), found {len(self.labels)}"
            )

    @property
    def n_frames(self) -> int:
        return self.points.shape[0]

    @property
    def n_markers(self) -> int:
        return self.points.shape[1]

    @property
    def mask(self) -> np.ndarray:
        """Gap mask ``(T, J)``: True where a marker is missing (any coordinate not finite)."""
        return ~np.isfinite(self.points).all(axis=2)

    def short_labels(self) -> list[str]:
        """Labels without a ``Subject:`` prefix (CMU and HDM05 share marker names that way)."""
        return [label.rsplit(":", 1)[-1] for label in self.labels]

    def with_points(self, points: np.ndarray) -> "MarkerSequence":
        """A copy carrying new points and the same labels, rate, units, source and meta."""
        return replace(self, points=np.asarray(points, dtype=np.float64), meta=dict(self.meta))

    def select(self, markers) -> "MarkerSequence":
        """A copy with only the given marker indices (or labels)."""
        index = [self.labels.index(m) if isinstance(m, str) else int(m) for m in markers]
        meta = dict(self.meta)
        if "point_index" in meta:
            meta["point_index"] = [meta["point_index"][i] for i in index]
        if meta.get("filled") is not None:          # (T, J) mask of filled samples, per marker
            meta["filled"] = np.asarray(meta["filled"])[:, index]
        if meta.get("confidence") is not None:      # (T, J) keypoint confidences (OpenPose)
            meta["confidence"] = np.asarray(meta["confidence"])[:, index]
        return replace(self, points=self.points[:, index].copy(),
                       labels=[self.labels[i] for i in index], meta=meta)

    def duplicates(self) -> dict[str, list[int]]:
        """Labels that name more than one marker, with their indices."""
        where: dict[str, list[int]] = {}
        for j, label in enumerate(self.labels):
            where.setdefault(label, []).append(j)
        return {label: idx for label, idx in where.items() if len(idx) > 1}

    def merge_duplicates(self) -> "MarkerSequence":
        """A copy with one marker per label: the first marker of a duplicated label, its missing
        samples taken from the later ones where those are observed (their union)."""
        dups = self.duplicates()
        if not dups:
            return self
        points = self.points.copy()
        for idx in dups.values():
            for j in idx[1:]:
                take = ~np.isfinite(points[:, idx[0]]).all(axis=1) & np.isfinite(
                    self.points[:, j]).all(axis=1)
                points[take, idx[0]] = self.points[take, j]
        drop = {j for idx in dups.values() for j in idx[1:]}
        keep = [j for j in range(self.n_markers) if j not in drop]
        return self.with_points(points).select(keep)

    def __repr__(self) -> str:
        missing = 100.0 * self.mask.mean() if self.points.size else 0.0
        name = self.source.name if self.source else "<memory>"
        return (f"MarkerSequence({name}: {self.n_frames} frames x {self.n_markers} markers, "
                f"{self.rate:g} Hz, {self.units}, {missing:.1f}% missing)")
