"""``fill()``: the one entry point that validates input, runs a registered solver and returns the
same kind of object it was given, observed samples bit-for-bit unchanged."""
from __future__ import annotations

import warnings

import numpy as np
import torch

from .metrics import gap_runs
from .sequence import MarkerSequence
from .solvers import available, get_solver

#: Preferred default, best first; the first registered one is used when ``method`` is not given.
DEFAULT_METHODS = ("tucker_tnn", "tucker", "pchip")


class UnfilledWarning(UserWarning):
    """Some gaps were left unfilled (a marker never observed, or a gap longer than ``max_gap``)."""


def methods() -> list[str]:
    """The registered method names."""
    return available()


def default_method() -> str:
    return next(m for m in DEFAULT_METHODS if m in available())


def fill(data, method: str | None = None, *, mask=None, max_gap: int | None = None,
         **params):
    """Fill the gaps of a recording.

    Parameters
    ----------
    data : MarkerSequence, ndarray or torch.Tensor of shape (T, J, 3)
        NaN marks a missing coordinate; a sample with any NaN coordinate counts as missing.
    method : str, optional
        A name from :func:`methods` (default: the best registered, see ``DEFAULT_METHODS``).
    mask : array (T, J) of bool, optional
        Extra samples to treat as missing (True = missing), on top of the NaNs.
    max_gap : int, optional
        Gaps longer than this many frames are left unfilled (NaN).
    **params
        Hyperparameters of the method (see ``torchfill methods``).

    Returns
    -------
    The same kind as ``data`` (a new object): a MarkerSequence, an ndarray, or a tensor on the same
    device and of the same dtype. Wherever the input was finite (and not masked), the output is the
    input bit-for-bit. Markers never observed stay NaN, with an :class:`UnfilledWarning`.
    """
    method = method or default_method()
    solver = get_solver(method, **params)   # validates the method and hyperparameters first
    points, kind = _as_tensor(data)
    missing = ~torch.isfinite(points).all(dim=2)
    if mask is not None:
        mask = torch.as_tensor(np.asarray(mask, dtype=bool), device=points.device)
        if mask.shape != missing.shape:
            raise ValueError(f"mask expected shape {tuple(missing.shape)}, found {tuple(mask.shape)}")
        missing = missing | mask
    out = points.clone()
    if mask is not None:
        out[mask] = float("nan")
    never = missing.all(dim=0)
    if bool(never.any()):
        names = _marker_names(data, never)
        warnings.warn(f"{int(never.sum())} marker(s) never observed, left unfilled: {names}",
                      UnfilledWarning, stacklevel=2)
    todo = missing & ~never
    if bool(todo.any()):
        keep = torch.nonzero(~never).flatten()
        Xk = torch.where(missing[:, keep, None], torch.nan, points[:, keep])
        filled = solver.fit_transform(Xk, mask=missing[:, keep])
        part = out[:, keep]
        part = torch.where(todo[:, keep, None] & ~torch.isfinite(part), filled.to(out.dtype), part)
        out[:, keep] = part
    if max_gap is not None:
        out = _unfill_long_gaps(out, missing, max_gap)
    return _as_kind(out, kind, data, method)


def _as_tensor(data) -> tuple[torch.Tensor, str]:
    if isinstance(data, MarkerSequence):
        X, kind = torch.from_numpy(np.array(data.points, dtype=np.float64)), "sequence"
    elif isinstance(data, torch.Tensor):
        X, kind = data.detach().clone(), "tensor"
        if not X.is_floating_point():
            X = X.to(torch.float64)
    else:
        arr = np.asarray(data)
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"expected numeric marker data, found dtype {arr.dtype}")
        X, kind = torch.from_numpy(np.array(arr, dtype=np.float64)), "array"
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"expected marker data of shape (T, J, 3), found {tuple(X.shape)}")
    if X.shape[0] < 2 or X.shape[1] < 1:
        raise ValueError(f"expected at least 2 frames and 1 marker, found {tuple(X.shape)}")
    if bool(torch.isinf(X).any()):
        raise ValueError("marker data contains infinite values; use NaN for missing samples")
    return X, kind


def _as_kind(out: torch.Tensor, kind: str, data, method: str):
    if kind == "tensor":
        return out
    points = out.cpu().numpy()
    if kind == "array":
        return points
    seq = data.with_points(points)
    seq.meta["filled"] = data.mask & np.isfinite(points).all(axis=2)
    seq.meta["fill_method"] = method
    return seq


def _unfill_long_gaps(out: torch.Tensor, missing: torch.Tensor, max_gap: int) -> torch.Tensor:
    if max_gap < 0:
        raise ValueError(f"max_gap expected >= 0, found {max_gap}")
    long = [(j, a, b) for j, a, b in gap_runs(missing.cpu().numpy()) if b - a > max_gap]
    for j, a, b in long:
        out[a:b, j] = torch.nan
    if long:
        warnings.warn(f"{len(long)} gap(s) longer than max_gap={max_gap} frames left unfilled",
                      UnfilledWarning, stacklevel=3)
    return out


def _marker_names(data, which: torch.Tensor) -> str:
    idx = torch.nonzero(which).flatten().tolist()
    if isinstance(data, MarkerSequence):
        return ", ".join(data.labels[i] for i in idx)
    return ", ".join(map(str, idx))
