"""Training recordings (the subject's other trials) matched to the recording to fill: by marker
label, in its units, at its rate."""
from __future__ import annotations

import warnings

import numpy as np
import torch

from .sequence import MarkerSequence


def align_training(training, data, keep: list[int], n_markers: int) -> list[torch.Tensor]:
    """Training recordings as tensors whose markers match ``data``'s kept markers, in order: a
    MarkerSequence by label (markers it lacks are NaN, with a warning), in ``data``'s units and
    at its rate (nearest frame); an array as it is."""
    data_shape = data.points.shape if isinstance(data, MarkerSequence) else (
        data.shape if hasattr(data, "shape") else np.shape(data))
    D = data_shape[2]                                                          # coordinates
    if isinstance(training, (MarkerSequence, np.ndarray, torch.Tensor)):
        training = [training]
    labels = data.short_labels() if isinstance(data, MarkerSequence) else None
    aligned = []
    for item in training:
        if isinstance(item, MarkerSequence):
            if labels is None:
                raise ValueError("training recordings given as MarkerSequence need labelled data: "
                                 "pass a MarkerSequence to fill(), or arrays as training")
            item = matched(item, data, [labels[j] for j in keep])
        else:
            item = np.asarray(item.detach().cpu() if isinstance(item, torch.Tensor) else item,
                              dtype=np.float64)
            if item.ndim != 3 or item.shape[1:] != (n_markers, D):
                raise ValueError(f"training array expected shape (T, {n_markers}, {D}) like the "
                                 f"recording to fill, found {item.shape}")
            item = item[:, keep]
        aligned.append(torch.from_numpy(np.array(item, dtype=np.float64)))
    return aligned


def matched(item: MarkerSequence, data: MarkerSequence, names: list[str]) -> np.ndarray:
    """``item``'s points for the markers ``names`` (NaN for those it lacks, with a warning), in
    ``data``'s units, resampled to ``data``'s rate on the nearest frame; a new array."""
    own = {name: i for i, name in enumerate(item.short_labels())}
    have = [j for j, name in enumerate(names) if name in own]
    source = item.source.name if item.source else "training recording"
    if not have:
        raise ValueError(f"{source}: shares no marker label with the recording to fill")
    if len(have) < len(names):
        absent = [name for name in names if name not in own]
        warnings.warn(f"{source}: lacks {len(absent)} marker(s) of the recording to fill, learned "
                      f"from the recording alone: {', '.join(absent[:8])}"
                      f"{' ...' if len(absent) > 8 else ''}", UserWarning, stacklevel=4)
    points = np.full((item.n_frames, len(names), item.points.shape[2]), np.nan)
    points[:, have] = item.points[:, [own[names[j]] for j in have]]
    points *= data.per_mm() / item.per_mm()
    if item.rate and data.rate and abs(item.rate - data.rate) > 1e-9 * data.rate:
        T = max(1, int(round(item.n_frames * data.rate / item.rate)))
        frames = np.minimum(np.round(np.arange(T) * item.rate / data.rate).astype(int),
                            item.n_frames - 1)
        points = points[frames]
    return points
