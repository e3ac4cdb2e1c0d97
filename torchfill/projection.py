"""2-D views of 3-D recordings: stand-ins for video keypoint tracks (OpenPose-like data).

No real OpenPose data is shared with the project, so the 2-D experiments (Li et al. 2020, Table 3)
run on projections of the 3-D marker recordings. :func:`side_view` is the one projection used
everywhere (experiments/pca_2d.yaml, the tests): an orthographic camera looking
horizontally, perpendicular to the recording's main horizontal direction, i.e. a side view of a
walk. Orthographic keeps the data linear in the 3-D positions; a real camera adds perspective, which
changes little for a subject far from it compared with its size.
"""
from __future__ import annotations

import numpy as np

from .sequence import MarkerSequence

_AXES = {"x": 0, "y": 1, "z": 2}


def side_axes(points: np.ndarray, up: str = "z") -> tuple[np.ndarray, np.ndarray]:
    """The image axes ``(u, v)`` (unit 3-vectors) of the side view of ``points`` (T, J, 3).

    ``v`` is the vertical axis ``up``; ``u`` is the first principal direction of the observed
    marker positions projected on the horizontal plane (the direction of travel of a walk, the
    widest spread otherwise), signed so that the motion goes towards +u.
    """
    if up not in _AXES:
        raise ValueError(f"up expected one of {', '.join(_AXES)}, found {up!r}")
    v = np.zeros(3)
    v[_AXES[up]] = 1.0
    flat = points.reshape(-1, 3)
    flat = flat[np.isfinite(flat).all(axis=1)]
    if flat.shape[0] < 2:
        raise ValueError("a side view needs at least 2 observed samples")
    horizontal = flat - np.outer(flat @ v, v)
    horizontal = horizontal - horizontal.mean(axis=0)
    _, _, Vt = np.linalg.svd(horizontal, full_matrices=False)
    u = Vt[0] - (Vt[0] @ v) * v
    u /= np.linalg.norm(u)
    finite = np.isfinite(points).all(axis=2)                   # (T, J)
    count = finite.sum(axis=1)
    centroid = np.where(finite[..., None], points, 0.0).sum(axis=1) / np.maximum(count, 1)[:, None]
    seen = np.flatnonzero(count > 0)
    if seen.size >= 2 and (centroid[seen[-1]] - centroid[seen[0]]) @ u < 0:
        u = -u
    return u, v


def side_view(seq: MarkerSequence, up: str = "z") -> MarkerSequence:
    """Orthographic side view of a 3-D recording: a ``(T, J, 2)`` MarkerSequence (same labels,
    rate and units; image coordinates ``(u, v)`` = along the main horizontal direction, up).

    Missing samples stay missing. See :func:`side_axes` for the camera.
    """
    if seq.points.shape[2] != 3:
        raise ValueError(f"side_view expects 3-D points, found shape {seq.points.shape}")
    u, v = side_axes(seq.points, up)
    points = np.stack([seq.points @ u, seq.points @ v], axis=2)
    meta = {"projection": {"kind": "orthographic side view", "u": u.tolist(), "v": v.tolist()}}
    return MarkerSequence(points=points, labels=list(seq.labels), rate=seq.rate, units=seq.units,
                          source=None, meta=meta)
