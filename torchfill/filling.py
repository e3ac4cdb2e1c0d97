"""``fill()``: the one entry point that validates input, runs a registered solver and returns the
same kind of object it was given, observed samples bit-for-bit unchanged."""
from __future__ import annotations

import time
import warnings
from collections.abc import Callable

import numpy as np
import torch

from .metrics import gap_runs
from .sequence import MarkerSequence
from .solvers import available, get_solver
from .solvers.auto import holdout_std

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
         progress: Callable[[dict], None] | None = None, return_std: bool = False, **params):
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
    progress : callable, optional
        Called with each iteration's diagnostics (a dict from the solver's ``history_``).
    return_std : bool
        Also return ``std`` (T, J): the estimated standard deviation of each coordinate's error at
        each filled sample, in the data's units, NaN where observed (``auto`` estimates it from its
        hold-outs; other methods get their held-out error on gaps of each kind, one extra fit; see
        torchfill/solvers/auto.py). A MarkerSequence also carries it as ``meta["std"]``.
    **params
        Hyperparameters of the method (see ``torchfill methods``). ``training=`` (for the PCA
        methods) takes other recordings: MarkerSequences are matched to ``data`` by marker label
        (``Subject:`` prefixes ignored), arrays must already have ``data``'s markers in order.

    Returns
    -------
    The same kind as ``data`` (a new object): a MarkerSequence, an ndarray, or a tensor on the same
    device and of the same dtype. Wherever the input was finite (and not masked), the output is the
    input bit-for-bit. Markers never observed stay NaN, with an :class:`UnfilledWarning`.
    With ``return_std=True``, the pair ``(filled, std)``, ``std`` of the same kind (ndarray for a
    MarkerSequence).
    """
    method = method or default_method()
    if max_gap is not None and max_gap < 0:
        raise ValueError(f"max_gap expected >= 0, found {max_gap}")
    get_solver(method, **{k: v for k, v in params.items() if k != "training"})  # validate early
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
    given = out.clone() if max_gap is not None else None   # the input's own finite coordinates
    never = missing.all(dim=0)
    if bool(never.any()):
        names = _marker_names(data, never)
        warnings.warn(f"{int(never.sum())} marker(s) never observed, left unfilled: {names}",
                      UnfilledWarning, stacklevel=2)
    todo = missing & ~never
    info = {"method": method, "n_iter": 0, "seconds": 0.0}
    std = torch.full(missing.shape, float("nan"), dtype=out.dtype, device=out.device)
    if bool(todo.any()):
        keep = torch.nonzero(~never).flatten()
        if params.get("training") is not None:
            params["training"] = _align_training(params["training"], data, keep.tolist(),
                                                 points.shape[1])
        solver = get_solver(method, **params)
        Xk = torch.where(missing[:, keep, None], torch.nan, points[:, keep])
        start = time.perf_counter()
        filled = solver.fit(Xk, missing[:, keep], callback=progress).transform(Xk)
        info.update(n_iter=solver.n_iter_, seconds=time.perf_counter() - start)
        part = out[:, keep]
        part = torch.where(todo[:, keep, None] & ~torch.isfinite(part), filled.to(out.dtype), part)
        out[:, keep] = part
        if return_std:
            est = getattr(solver, "std_", None)
            if est is None:
                est = holdout_std(method, params, Xk, missing[:, keep], seed=solver.seed)
            std[:, keep] = torch.where(todo[:, keep], est.to(std), std[:, keep])
    if max_gap is not None:
        out = _unfill_long_gaps(out, given, missing, max_gap)
    if not return_std:
        return _as_kind(out, kind, data, info)
    std = torch.where(torch.isfinite(out).all(dim=2) & missing, std, float("nan"))
    result = _as_kind(out, kind, data, info)
    if kind == "tensor":
        return result, std
    if kind == "sequence":
        result.meta["std"] = std.cpu().numpy()
    return result, std.cpu().numpy()


def _align_training(training, data, keep: list[int], n_markers: int) -> list[torch.Tensor]:
    """Training recordings as tensors whose markers match ``data``'s kept markers, in order."""
    if isinstance(training, (MarkerSequence, np.ndarray, torch.Tensor)):
        training = [training]
    labels = data.short_labels() if isinstance(data, MarkerSequence) else None
    aligned = []
    for item in training:
        if isinstance(item, MarkerSequence):
            if labels is None:
                raise ValueError("training recordings given as MarkerSequence need labelled data: "
                                 "pass a MarkerSequence to fill(), or arrays as training")
            own = {name: i for i, name in enumerate(item.short_labels())}
            absent = [name for name in (labels[j] for j in keep) if name not in own]
            if absent:
                name = item.source.name if item.source else "training recording"
                raise ValueError(f"{name}: lacks {len(absent)} marker(s) of the recording to fill: "
                                 f"{', '.join(absent[:8])}{' ...' if len(absent) > 8 else ''}")
            item = item.points[:, [own[labels[j]] for j in keep]]
        else:
            item = np.asarray(item.detach().cpu() if isinstance(item, torch.Tensor) else item,
                              dtype=np.float64)
            if item.ndim != 3 or item.shape[1:] != (n_markers, 3):
                raise ValueError(f"training array expected shape (T, {n_markers}, 3) like the "
                                 f"recording to fill, found {item.shape}")
            item = item[:, keep]
        aligned.append(torch.from_numpy(np.array(item, dtype=np.float64)))
    return aligned


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


def _as_kind(out: torch.Tensor, kind: str, data, info: dict):
    if kind == "tensor":
        return out
    points = out.cpu().numpy()
    if kind == "array":
        return points
    seq = data.with_points(points)
    seq.meta["filled"] = data.mask & np.isfinite(points).all(axis=2)
    seq.meta["fill_info"] = info
    return seq


def _unfill_long_gaps(out: torch.Tensor, given: torch.Tensor, missing: torch.Tensor,
                      max_gap: int) -> torch.Tensor:
    """Put the long gaps back as they were given (NaN, except finite coordinates of a sample
    that was only partly missing: those are observed and stay)."""
    long = [(j, a, b) for j, a, b in gap_runs(missing.cpu().numpy()) if b - a > max_gap]
    for j, a, b in long:
        out[a:b, j] = given[a:b, j]
    if long:
        warnings.warn(f"{len(long)} gap(s) longer than max_gap={max_gap} frames left unfilled",
                      UnfilledWarning, stacklevel=3)
    return out


def _marker_names(data, which: torch.Tensor) -> str:
    idx = torch.nonzero(which).flatten().tolist()
    if isinstance(data, MarkerSequence):
        return ", ".join(data.labels[i] for i in idx)
    return ", ".join(map(str, idx))
