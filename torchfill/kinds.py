"""The kinds of data ``fill()`` takes and gives back: a MarkerSequence, an ndarray or a tensor
(one recording ``(T, J, D)``), or a list of recordings."""
from __future__ import annotations

import numpy as np
import torch

from .sequence import MarkerSequence
from .solvers.base import refuse_grad


def recordings(data) -> bool:
    """Whether ``data`` is a list (or tuple) of recordings rather than one nested-list array."""
    return isinstance(data, (list, tuple)) and len(data) > 0 and all(
        isinstance(d, (MarkerSequence, np.ndarray, torch.Tensor)) for d in data)


def as_tensor(data) -> tuple[torch.Tensor, str]:
    if isinstance(data, MarkerSequence):
        X, kind = torch.from_numpy(np.array(data.points, dtype=np.float64)), "sequence"
    elif isinstance(data, torch.Tensor):
        refuse_grad(data, "fill")
        X, kind = data.detach().clone(), "tensor"
        if not X.is_floating_point():
            X = X.to(torch.float64)
    else:
        arr = np.asarray(data)
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"expected numeric marker data, found dtype {arr.dtype}")
        X, kind = torch.from_numpy(np.array(arr, dtype=np.float64)), "array"
    if X.ndim != 3 or X.shape[2] < 1:
        raise ValueError(f"expected marker data of shape (T, J, D) (D = 3: xyz, 2: image "
                         f"keypoints), found {tuple(X.shape)}")
    if X.shape[0] < 2 or X.shape[1] < 1:
        raise ValueError(f"expected at least 2 frames and 1 marker, found {tuple(X.shape)}")
    if bool(torch.isinf(X).any()):
        raise ValueError("marker data contains infinite values; use NaN for missing samples")
    return X, kind


def as_kind(out: torch.Tensor, kind: str, data, info: dict, missing: torch.Tensor):
    if kind == "tensor":
        return out
    points = out.cpu().numpy()
    if kind == "array":
        return points
    seq = data.with_points(points)
    seq.meta["filled"] = missing.cpu().numpy() & np.isfinite(points).all(axis=2)  # mask= too
    seq.meta["fill_info"] = info
    return seq
