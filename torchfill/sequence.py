"""The one in-memory form of a recording: :class:`MarkerSequence`; its units and axes."""
from __future__ import annotations

import difflib
import re
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

    def per_mm(self) -> float:
        """This recording's units per mm (see :func:`per_mm`)."""
        return per_mm(self.units)

    def select(self, markers) -> "MarkerSequence":
        """A copy with only the given marker indices (or labels)."""
        index = [self._marker(m) for m in markers]
        meta = dict(self.meta)
        if "point_index" in meta:
            meta["point_index"] = [meta["point_index"][i] for i in index]
        if meta.get("filled") is not None:          # (T, J) mask of filled samples, per marker
            meta["filled"] = np.asarray(meta["filled"])[:, index]
        if meta.get("confidence") is not None:      # (T, J) keypoint confidences (OpenPose)
            meta["confidence"] = np.asarray(meta["confidence"])[:, index]
        if meta.get("verdict") is not None:         # (T, J) qc verdict codes of the fills
            meta["verdict"] = np.asarray(meta["verdict"])[:, index]
        return replace(self, points=self.points[:, index].copy(),
                       labels=[self.labels[i] for i in index], meta=meta)

    def _marker(self, m) -> int:
        """The index of marker ``m`` (a label, or an index); one-line ``KeyError`` otherwise."""
        if isinstance(m, str):
            if m in self.labels:
                return self.labels.index(m)
            short = self.short_labels()
            if short.count(m) == 1:
                return short.index(m)
            near = difflib.get_close_matches(m, self.labels, n=1)
            raise KeyError(f"no marker {m!r}" + (f" (did you mean {near[0]!r}?)" if near else
                                                  f"; the labels are {self.labels[:8]}..."))
        if isinstance(m, (bool, np.bool_)) or not isinstance(m, (int, np.integer)):
            raise KeyError(f"markers are chosen by label or index, found {m!r}")
        if not -self.n_markers <= int(m) < self.n_markers:
            raise KeyError(f"marker index {int(m)} out of range for {self.n_markers} markers")
        return int(m) % self.n_markers

    def __getitem__(self, key) -> "MarkerSequence":
        """A copy of some frames and/or markers: ``seq[100:200]`` (frames), ``seq["LASI"]`` or
        ``seq[["LASI", "RASI"]]`` (markers by label), ``seq[:100, ["LASI", "RASI"]]`` (both).
        Frames are a slice with step 1 (``first_frame`` follows it) or indices; per-frame
        ``meta`` arrays (``filled``, ``time``, ...) are cut alike. A cut in frames is written as
        a fresh file (``source`` None): the source's other frames cannot be kept."""
        frames, markers = (key if isinstance(key, tuple) and len(key) == 2 else
                           (key, None) if not _labels_key(key) else (slice(None), key))
        out = self if markers is None else self.select(
            [markers] if isinstance(markers, (str, int, np.integer)) else markers)
        return out._frames(frames)

    def _frames(self, key) -> "MarkerSequence":
        T = self.n_frames
        if isinstance(key, slice):
            start, stop, step = key.indices(T)
            if step != 1:
                raise IndexError(f"frames are sliced with step 1, found step {step} "
                                 "(seq.points[::step] gives the array)")
            index, first = np.arange(start, max(start, stop)), self.first_frame + start
        else:
            index = np.arange(T)[np.asarray(key)].reshape(-1)
            first = self.first_frame + (int(index[0]) if index.size else 0)
        if index.size == T and (index == np.arange(T)).all():
            return self
        meta = {k: (v[index] if isinstance(v, np.ndarray) and v.ndim and len(v) == T else v)
                for k, v in self.meta.items()}
        return replace(self, points=self.points[index].copy(), meta=meta, first_frame=first,
                       source=None)

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

    # -- units and axes ------------------------------------------------------------------------
    def in_units(self, units: str) -> "MarkerSequence":
        """A copy in ``units`` ("m", "cm" or "mm"): every coordinate scaled, nothing else."""
        k = unit_power(self.units, units)
        out = self.with_points(self.points * 10.0 ** k if k >= 0 else self.points / 10.0 ** -k)
        out.units = units
        return out

    def with_axes(self, axes) -> "MarkerSequence":
        """A copy with its axes turned: ``axes`` is ``"zup-to-yup"``, ``"yup-to-zup"`` or a
        signed permutation such as ``"x,z,-y"`` (see :func:`parse_axes`)."""
        if self.points.shape[2] != 3:
            raise ValueError(f"axes turn 3-D points, found {self.points.shape[2]}-D data")
        order, signs = parse_axes(axes)
        return self.with_points(self.points[..., list(order)] * np.asarray(signs, dtype=float))

    # -- the ecosystem's data types (each imported on use; see the ``interop`` extra) -----------
    def _axes(self) -> list[str]:
        return ["x", "y", "z"][: self.points.shape[2]]

    def _time(self) -> np.ndarray:
        return np.arange(self.n_frames) / float(self.rate)

    def to_pandas(self):
        """A :class:`pandas.DataFrame`: one row per frame, index ``time`` in seconds, columns a
        MultiIndex ``(marker, axis)`` with axis ``x``, ``y`` (, ``z``); NaN where missing.
        ``df.attrs`` holds ``rate`` and ``units`` (read back by :meth:`from_pandas`)."""
        import pandas as pd

        columns = pd.MultiIndex.from_product([self.labels, self._axes()], names=["marker", "axis"])
        df = pd.DataFrame(self.points.reshape(self.n_frames, -1).copy(), columns=columns,
                          index=pd.Index(self._time(), name="time"))
        df.attrs.update(rate=float(self.rate), units=self.units)
        return df

    @classmethod
    def from_pandas(cls, df, rate: float | None = None, units: str | None = None) -> "MarkerSequence":
        """A sequence from a DataFrame laid out as :meth:`to_pandas` writes it (MultiIndex columns
        ``(marker, axis)``, markers in the order they first appear). ``rate``: default
        ``df.attrs["rate"]``, else from the time index (seconds); ``units``: default
        ``df.attrs["units"]``, else "mm"."""
        if getattr(df.columns, "nlevels", 1) != 2:
            raise ValueError("expected DataFrame columns as a MultiIndex (marker, axis), found "
                             f"{df.columns.nlevels} level(s)")
        labels = list(dict.fromkeys(df.columns.get_level_values(0)))
        axes = list(dict.fromkeys(df.columns.get_level_values(1)))
        if len(axes) not in (2, 3) or df.shape[1] != len(labels) * len(axes):
            raise ValueError(f"expected 2 or 3 axes for each of the {len(labels)} markers, found "
                             f"{df.shape[1]} columns over axes {axes}")
        points = np.stack([df[m][axes].to_numpy(dtype=np.float64) for m in labels], axis=1)
        rate = _rate(rate, df.attrs.get("rate"), np.asarray(df.index, dtype=np.float64))
        return cls(points, labels, rate=rate, units=units or df.attrs.get("units", "mm"))

    def to_xarray(self):
        """An :class:`xarray.DataArray` with dims ``(time, marker, axis)`` (time in seconds) and
        attrs ``rate`` and ``units``; NaN where missing."""
        import xarray as xr

        return xr.DataArray(self.points.copy(), dims=("time", "marker", "axis"),
                            coords={"time": self._time(), "marker": list(self.labels),
                                    "axis": self._axes()},
                            attrs={"rate": float(self.rate), "units": self.units})

    @classmethod
    def from_xarray(cls, da, rate: float | None = None, units: str | None = None) -> "MarkerSequence":
        """A sequence from a DataArray with dims ``time``, ``marker``, ``axis`` (any order), as
        :meth:`to_xarray` writes it."""
        da = da.transpose("time", "marker", "axis")
        rate = _rate(rate, da.attrs.get("rate"), np.asarray(da["time"], dtype=np.float64))
        return cls(np.asarray(da.values, dtype=np.float64), [str(m) for m in da["marker"].values],
                   rate=rate, units=units or da.attrs.get("units", "mm"))

    def to_ktk(self):
        """A Kinetics Toolkit ``TimeSeries``: ``time`` in seconds, ``data[label]`` a ``(T, 4)``
        array ``[x, y, z, 1]`` (all NaN where missing, as ``ktk.read_c3d`` gives), the unit in
        ``info[label]["Unit"]``. 3-D markers with distinct labels only."""
        import kineticstoolkit as ktk

        if self.points.shape[2] != 3:
            raise ValueError(f"Kinetics Toolkit points are 3-D, found {self.points.shape[2]}-D data")
        if self.duplicates():
            raise ValueError(f"duplicate labels {sorted(self.duplicates())} cannot be TimeSeries "
                             "keys (see merge_duplicates())")
        ts = ktk.TimeSeries(time=self._time())
        ones = np.ones((self.n_frames, 1))
        for j, label in enumerate(self.labels):
            data = np.concatenate([self.points[:, j], ones], axis=1)
            data[~np.isfinite(self.points[:, j]).all(axis=1)] = np.nan
            ts.data[label] = data
            ts.add_info(label, "Unit", self.units, in_place=True)
        return ts

    @classmethod
    def from_ktk(cls, ts, rate: float | None = None, units: str | None = None) -> "MarkerSequence":
        """A sequence from a Kinetics Toolkit ``TimeSeries`` of points (``(T, 4)`` or ``(T, 3)``
        arrays, e.g. from ``ktk.read_c3d(...)["Points"]``); the unit from ``info[label]["Unit"]``
        (default "m", ktk's own), the rate from ``time``."""
        labels = list(ts.data)
        if not labels:
            raise ValueError("the TimeSeries holds no data")
        bad = [k for k in labels if np.ndim(ts.data[k]) != 2 or np.shape(ts.data[k])[1] not in (3, 4)]
        if bad:
            raise ValueError(f"expected (T, 4) or (T, 3) point arrays, found {bad[0]!r} of shape "
                             f"{np.shape(ts.data[bad[0]])}")
        points = np.stack([np.asarray(ts.data[k], dtype=np.float64)[:, :3] for k in labels], axis=1)
        info = getattr(ts, "info", None) or getattr(ts, "data_info", {})
        found = {info.get(k, {}).get("Unit") for k in labels} - {None}
        if units is None and len(found) > 1:
            raise ValueError(f"the points have several units {sorted(found)}; pass units=")
        rate = _rate(rate, None, np.asarray(ts.time, dtype=np.float64))
        return cls(points, labels, rate=rate, units=units or (found.pop() if found else "m"))

    def __repr__(self) -> str:
        missing = 100.0 * self.mask.mean() if self.points.size else 0.0
        name = self.source.name if self.source else "<memory>"
        return (f"MarkerSequence({name}: {self.n_frames} frames x {self.n_markers} markers, "
                f"{self.rate:g} Hz, {self.units}, {missing:.1f}% missing)")


def _labels_key(key) -> bool:
    """Whether an index names markers (a label or a list of labels) rather than frames."""
    if isinstance(key, str):
        return True
    return isinstance(key, (list, tuple)) and len(key) > 0 and all(isinstance(k, str) for k in key)


#: Power of ten of each length unit in metres (the one table of length units).
UNITS = {"m": 0, "cm": -2, "mm": -3}
#: The same units as units per mm (m 0.001, cm 0.1, mm 1).
UNITS_PER_MM = {units: 10.0 ** (UNITS["mm"] - power) for units, power in UNITS.items()}


def per_mm(units: str) -> float:
    """Length ``units`` per mm (see :data:`UNITS_PER_MM`); 1 for units that are no length
    unit (pixels)."""
    return UNITS_PER_MM.get((units or "mm").strip().lower(), 1.0)
#: Named axis turns: the new x, y, z as signed old axes.
AXES = {"zup-to-yup": "x,z,-y", "yup-to-zup": "x,-z,y"}


def unit_power(source: str, target: str) -> int:
    """``k`` such that a length in ``source`` units times ``10**k`` is in ``target`` units."""
    for units in (source, target):
        if units not in UNITS:
            raise ValueError(f"units expected one of {', '.join(UNITS)}, found {units!r}")
    return UNITS[source] - UNITS[target]


def parse_axes(axes) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """``(order, signs)`` of an axis turn: new coordinate ``i`` is ``signs[i] * old[order[i]]``.

    ``axes`` is a name of :data:`AXES` (``"zup-to-yup"``: a lab's Z-up frame to OpenSim's Y-up,
    x kept, y = z, z = -y), a text ``"x,z,-y"`` (each new axis a signed old one, every old axis
    once) or a sequence of three such items."""
    text = AXES.get(str(axes).strip().lower(), axes) if isinstance(axes, str) else axes
    items = [t.strip().lower() for t in (text.split(",") if isinstance(text, str) else text)]
    found = [re.fullmatch(r"([+-]?)([xyz])", t) for t in items]
    if len(items) != 3 or not all(found) or len({m.group(2) for m in found}) != 3:
        raise ValueError(f"axes expected {' or '.join(map(repr, AXES))} or a signed permutation "
                         f"of x, y, z such as 'x,z,-y', found {axes!r}")
    order = tuple("xyz".index(m.group(2)) for m in found)
    signs = tuple(-1 if m.group(1) == "-" else 1 for m in found)
    return order, signs


def _rate(rate: float | None, stored, time: np.ndarray) -> float:
    """Frames per second: ``rate``, else the stored one, else from a time axis in seconds."""
    for value in (rate, stored):
        if value is not None:
            return float(value)
    step = np.diff(time)
    if step.size == 0 or not np.all(np.isfinite(step)) or np.median(step) <= 0:
        raise ValueError("cannot tell the frame rate from the time axis; pass rate=")
    return float(f"{1.0 / np.median(step):.9g}")     # 1 / (1/120) is 120.00000000000043
