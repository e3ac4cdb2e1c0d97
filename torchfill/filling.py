"""``fill()``: the one entry point that validates input, runs a registered solver and returns the
same kind of object it was given, observed samples bit-for-bit unchanged."""
from __future__ import annotations

import functools
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from .constraints import constrain, constrain_candidates, meet_kept
from .qc import EST_CHECK_MM, alone, per_mm, untested
from .qc.finish import short_gap_fallback, std_bound
from .metrics import gap_runs
from .runtime.cache import clear_all as clear_kept
from .runtime.memory import trim_heap
from . import windows
from .sequence import MarkerSequence
from .solvers import available, get_solver
from .solvers.selection.candidates import PARTIAL
from .solvers.rigid import HOLDOUT_LAGS, body_size, segment_fill
from .solvers.rigid import clear_cache as clear_rigid_cache
from .solvers.session import TRAINING_FRAMES, spread_runs

_LOCK = threading.Lock()

#: Gaps longer than this (seconds) filled without rigid donors are named in a warning.
LONG_GAP_SECONDS = 10.0

#: Preferred default, best first; the first registered one is used when ``method`` is not given.
#: ``auto``: per gap, the candidate methods that fill gaps of that kind best on the recording's
#: own observed data (spatial models at trial ends and for groups of missing markers, rigid
#: segments where three segment-mates are seen, low-rank and interpolation inside), with its error
#: estimate (see torchfill/solvers/auto.py; numbers in docs/real-gaps.md).
DEFAULT_METHODS = ("auto", "tucker_tnn", "tucker", "pchip")


class UnfilledWarning(UserWarning):
    """Some gaps were left unfilled (a marker never observed, or a gap longer than ``max_gap``)."""


def methods() -> list[str]:
    """The registered method names."""
    return available()


def default_method() -> str:
    return next(m for m in DEFAULT_METHODS if m in available())


class _Default(int):
    """The default of an ``int`` argument, told apart from the same number given explicitly."""


_WINDOW = _Default(windows.WINDOW)


def fill(data, method: str | None = None, *, params: dict | None = None, training=None,
         mask=None, max_gap: int | None = None, window: int | None = _WINDOW,
         progress: bool | Callable[[dict], None] | None = False, constraints: bool = True,
         extrapolate: float | None = 0.25, return_std: bool = False, dtype=None,
         workers: int | None = None, segments=None, reject: float | None = None, **legacy):
    """Fill the gaps of a recording.

    Parameters
    ----------
    data : MarkerSequence, ndarray or torch.Tensor of shape (T, J, D), or a batch (B, T, J, D)
        D = 3 (markers, xyz) or 2 (image keypoints, xy); any D >= 1 for arrays and tensors. NaN
        marks a missing coordinate; a sample with any NaN coordinate counts as missing. A batch
        of arrays or tensors is filled sequence by sequence (``mask`` then ``(B, T, J)``) and
        returned as a batch. float16 / bfloat16 tensors are computed in float32 and returned in
        their own dtype.
    method : str, optional
        A name from :func:`methods` (default: the best registered, see ``DEFAULT_METHODS``).
    params : dict, optional
        Hyperparameters of the method (see ``torchfill methods``), e.g. ``{"max_iter": 200}``.
        They never mix with ``fill()``'s own arguments: ``fill(X, "pma", window=15)`` is an
        error (pma has a ``window`` of its own), ``params={"window": 15}`` sets pma's.
        Passing them as keyword arguments of ``fill()`` still works for one release, with a
        DeprecationWarning.
    training : MarkerSequence, ndarray or a list of them, optional
        Other recordings of the same marker set -- the subject's other trials -- for the methods
        that take them: the spatial models (``pma``, ``li``, ``lpr``, ``lgrnn``, ``glr``,
        ``pca_gloersen``) learn from their observed frames too (see
        :mod:`torchfill.solvers.session`), ``auto`` adds those as candidates ``NAME+session``
        that its hold-out weighs against the recording's own, ``pca_train``/``pca_blackout``
        take them as their training set; a marker never observed in ``data`` is placed from its
        segment-mates with the local coordinates the training shows, where that rigid fill's
        own error estimate is small. MarkerSequences are matched to ``data`` by marker label
        (``Subject:`` prefixes ignored; markers one lacks are NaN there, with a warning; none in
        common is an error), put in ``data``'s units and resampled to its rate (nearest frame);
        arrays must already have ``data``'s markers in order. They are never changed.
    mask : array (T, J) of bool, optional
        Extra samples to treat as missing (True = missing), on top of the NaNs.
    max_gap : int, optional
        Gaps longer than this many frames are left unfilled (NaN).
    window : int or None
        Recordings longer than this many frames are filled in overlapping windows, blended with a
        cross-fade (see :mod:`torchfill.windows`: the window grows to 6x the longest gap, the
        overlap is 2x the longest gap), so time grows linearly with the length and memory is
        bounded. ``None`` fills the whole recording at once.
    progress : bool or callable
        ``True``: a bar with percent and time left over the whole fill on a terminal (after
        2 s), one summary line on stderr otherwise; ``False`` (default): nothing; a callable
        receives every record: the solver's iteration diagnostics (a dict from its ``history_``,
        or ``auto``'s ``fit``/``fits`` as candidates finish) with ``window``, ``windows`` and
        ``max_iter`` (see :mod:`torchfill.progress`).
    constraints : bool
        Make the fill obey the body (default): rigid donors, continuity at gap edges, no steps
        beyond the observed motion, samples inside the observed volume, no invented blackout
        frames (see :mod:`torchfill.constraints`). ``False`` returns the method's own fill, as in
        its paper.
    extrapolate : float or None
        Seconds a gap touching a trial end may be extrapolated in time (default 0.25 s); the rest
        is left NaN with a warning. Samples filled from rigid donors, and -- for a spatial method
        such as the default (``Solver.spatial``) -- samples in frames with at least three markers
        seen, are not extrapolations in time and are not cut. Needs the rate of a
        MarkerSequence: arrays and tensors have no limit. With a limit, the samples of a marker
        never seen in two consecutive frames are left NaN too, where the fill has an error
        estimate (the default's): it has no observed motion to go on, and neither has the
        estimate (see :func:`torchfill.qc.untested`; one warning names the markers), and so
        are the samples of a marker whose segment-mates are never observed, where its estimated
        error is above the QC's check level: the fill alone would pose the segment (see
        :func:`torchfill.qc.alone`; one warning). None: no limit, every sample filled. Only
        with ``constraints``.
    return_std : bool
        Also return ``std`` (T, J): the estimated standard deviation of each coordinate's error at
        each filled sample, in the data's units, NaN where observed or left unfilled (``auto``
        estimates it from its hold-outs; other methods get their held-out error on gaps of each
        kind, one extra fit; see torchfill/solvers/auto.py). A MarkerSequence also carries it as
        ``meta["std"]``.
    dtype : torch.dtype or str, optional
        The floating dtype the method computes in (``"float32"`` / ``"float64"``; default: the
        method's ``fill_dtype``, float32 for ``tucker`` and ``tucker_tnn`` -- about twice as fast
        -- else float64). Only the filled samples come from that computation: the observed ones
        and the output's dtype are the input's.
    workers : int, optional
        Windows solved at once, in threads that share torch's intra-op threads out (default and
        most: that thread count, ``torch.get_num_threads()``; on CPU only; see
        :func:`torchfill.runtime.threads.thread_map`). The first window runs alone and the fills blend in
        window order, so a fill does not depend on which window finishes first; it does depend on
        the threads per window, which change how float32 sums round (accuracy the same).
    reject : float, optional
        Leave NaN the filled samples whose estimated 3-D error is above this many mm (at a trial
        end from the first such sample on; inside a trial the whole gap when its RMS estimate is
        above it), with one warning; needs the error estimate (``auto``'s own) and a
        MarkerSequence in mm, cm or m. Default None: keep every fill and let ``torchfill qc``
        flag it -- on the OpenSim IK benchmark (docs/ik.md) leaving such samples out made the
        joint angles worse (mean 4.63 deg at 30 mm, 3.22 at 60 mm, 2.93 keeping them).
    segments : optional
        Which markers move together (see :mod:`torchfill.segments`): a dict segment name ->
        marker labels, a path to a segments YAML file (``torchfill info --segments`` prints one),
        ``"names"`` (the built-in marker-set tables), ``"data"`` (near-rigid clusters found in the
        recording) or None (the tables when the labels fit them, else found from the data). Used
        by the ``rigid`` method, ``auto``'s rigid candidate and the constraints' rigid donors.
    **legacy
        Deprecated: hyperparameters of the method as keyword arguments (use ``params``).

    Returns
    -------
    The same kind as ``data`` (a new object): a MarkerSequence, an ndarray, or a tensor on the same
    device and of the same dtype. Wherever the input was finite (and not masked), the output is the
    input bit-for-bit. Markers never observed stay NaN (unless ``training`` places them), with an
    :class:`UnfilledWarning`.
    With ``return_std=True``, the pair ``(filled, std)``, ``std`` of the same kind (ndarray for a
    MarkerSequence).
    """
    prior = _previous_fill(data, mask)
    if prior is not None:
        return _refill(data, prior, method, mask=mask, max_gap=max_gap, window=window,
                       progress=progress, constraints=constraints, extrapolate=extrapolate,
                       return_std=return_std, dtype=dtype, workers=workers, segments=segments,
                       reject=reject, params=params, training=training, **legacy)
    method = default_method() if method is None else method
    if not isinstance(method, str) or not method.strip():
        raise ValueError(f"method expected one of {', '.join(available())}, found {method!r}")
    params, training = _solver_params(method, params, training, legacy, window is not _WINDOW)
    again = functools.partial(fill, method=method, params=params, training=training,
                              max_gap=max_gap, window=window, progress=progress,
                              constraints=constraints, extrapolate=extrapolate,
                              return_std=return_std, dtype=dtype, workers=workers,
                              segments=segments, reject=reject)
    if not isinstance(data, MarkerSequence) and np.ndim(data) == 4:
        return _fill_batch(data, mask, again)
    if isinstance(data, torch.Tensor) and data.dtype in (torch.float16, torch.bfloat16):
        # computed in float32; every float16/bfloat16 value is exact in float32 and back
        done = again(data.float(), mask=mask)
        return tuple(d.to(data.dtype) for d in done) if return_std else done.to(data.dtype)
    if max_gap is not None and max_gap < 0:
        raise ValueError(f"max_gap expected >= 0, found {max_gap}")
    if window is not None and (isinstance(window, bool) or not isinstance(window, int) or window < 2):
        raise ValueError(f"window expected an int >= 2 or None, found {window!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers expected an int >= 1 or None, found {workers!r}")
    if not (progress is None or isinstance(progress, bool) or callable(progress)):
        raise ValueError(f"progress expected True, False or a callable, found {progress!r}")
    return fill_case(data, method, params, training=training, mask=mask, max_gap=max_gap,
                     window=window, progress=progress, constraints=constraints,
                     extrapolate=extrapolate, return_std=return_std, dtype=dtype, workers=workers,
                     segments=segments, reject=reject)


def fill_case(data, method: str, params: dict, *, training=None, mask=None,
              max_gap: int | None = None, window: int | None = windows.WINDOW,
              progress: bool | Callable[[dict], None] | None = False, constraints: bool = True,
              extrapolate: float | None = 0.25, return_std: bool = False, dtype=None,
              workers: int | None = None, segments=None, reject: float | None = None,
              solve: Callable | None = None):
    """Fill one recording ``(T, J, D)``: prepare -> solve -> finish.

    The one path of a fill: :func:`fill` calls it once it has checked its arguments (and split a
    batch, widened half precision, set earlier fills aside), and the experiment runner
    (:mod:`torchfill.lightning.runner`) calls it for every case, so that an experiment scores what
    ``fill()`` returns; the papers' protocols are arguments (``constraints=False``,
    ``extrapolate=None``, ``window=None``, ``dtype``). Arguments and result as :func:`fill`'s;
    ``params``: the method's hyperparameters (a dict; not changed); and

    solve : callable, optional
        ``solve(solver, X, missing, data, callback, part)`` fits ``solver`` to one window ``X``
        (NaN where ``missing``; ``data``: its fit data such as ``training``; ``callback``: takes
        each iteration's record; ``part``: ``(frames, markers)``, the window's frame slice and
        marker indices in ``data``) as ``solver.fit`` does -- the default; the runner drives the
        same solver under a Lightning Trainer, one ``step()`` per training step.
    """
    case = _prepare(data, method, dict(params), training, mask, dtype, segments, constraints,
                    max_gap is not None)
    if bool(case.todo.any()):
        _solve(case, window, workers, progress, constraints, return_std, solve or _fit)
    if case.training is not None and bool(case.never.any()):
        _place_from_training(case)
    return _finish(case, constraints, extrapolate, reject, max_gap, return_std)


@dataclass
class _Case:
    """A recording on its way through :func:`fill_case` (tensors ``(T, J, D)`` / ``(T, J)``)."""

    data: object                     # what the caller gave (labels, rate, units, kind)
    kind: str                        # "sequence", "array" or "tensor"
    method: str
    params: dict                     # the method's hyperparameters (with segments, carry)
    solver: object                   # a solver of ``method`` (validated; its class attributes)
    work: torch.dtype | None         # the dtype the method computes in (None: the data's)
    points: torch.Tensor | None      # the input (dropped once the windows are cut)
    out: torch.Tensor                # the result being built: the input, NaN at ``mask``
    given: torch.Tensor | None       # the input's own coordinates (for ``max_gap``)
    own: torch.Tensor                # coordinates the input had: never changed
    missing: torch.Tensor            # samples to fill (NaN or ``mask``)
    unfit: torch.Tensor              # samples the solver does not see (missing or corrupt)
    never: torch.Tensor              # markers never observed (J,)
    todo: torch.Tensor               # missing samples of markers observed somewhere
    training: object
    seg_idx: dict | None             # segments as marker indices (None: not needed)
    info: dict
    std: torch.Tensor
    shown: object = None             # the progress display, while solving
    anchored: torch.Tensor | None = None     # fills the soft distances keep (auto's segments)
    placed: torch.Tensor | None = None       # never-observed markers placed from the training


def _prepare(data, method, params, training, mask, dtype, segments, constraints,
             keep_given: bool) -> _Case:
    """Validate the method and data, and find what is missing, what the solver may see and the
    segments."""
    solver = get_solver(method, **params)                           # validate early
    work = _work_dtype(dtype, solver)
    if training is not None and "training" not in solver.fit_data:
        raise ValueError(f"{method}: takes no training data; methods that do: "
                         f"{', '.join(m for m in methods() if 'training' in get_solver(m).fit_data)}")
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
    unfit = missing | _huge(points, missing)     # what the solver does not see
    never = unfit.all(dim=0)
    if bool(never.any()) and training is None:
        _warn_never(data, never)
    todo = missing & ~never
    info = {"method": method, "n_iter": 0, "seconds": 0.0, "windows": 0,
            "dtype": str(work or points.dtype).removeprefix("torch.")}
    seg_idx = None
    if (bool(todo.any()) or training is not None) and points.shape[2] == 3 and (
            constraints or segments is not None or "segments" in solver.declared_params()):
        seg_idx = _segment_indices(segments, data, points, unfit)
    return _Case(data, kind, method, params, solver, work, points, out,
                 out.clone() if keep_given else None, torch.isfinite(out), missing, unfit, never,
                 todo, training, seg_idx, info,
                 torch.full(missing.shape, float("nan"), dtype=out.dtype, device=out.device))


def _solve(case: _Case, window, workers, progress, constraints: bool, return_std: bool,
           solve: Callable) -> None:
    """Solve the markers observed somewhere, window by window, and write their fill (and error
    estimate) into ``case``."""
    params, unfit, method = case.params, case.unfit, case.method
    keep = torch.nonzero(~case.never).flatten()
    kept_segments = None
    if case.seg_idx is not None:
        at = {int(j): i for i, j in enumerate(keep.tolist())}
        kept_segments = {s: [at[j] for j in m if j in at] for s, m in case.seg_idx.items()}
    declared = case.solver.declared_params()
    if kept_segments is not None and "segments" in declared:
        params["segments"] = kept_segments
    if kept_segments is not None and "candidate_params" in declared:
        given = dict(params.get("candidate_params") or {})      # auto's rigid candidate
        given["rigid"] = {"segments": kept_segments, **given.get("rigid", {})}
        params["candidate_params"] = given
    extra = {}
    if constraints and "post" in case.solver.fit_data:     # auto scores fills as they come out
        extra["post"] = functools.partial(constrain_candidates, segments=kept_segments)
    if case.training is not None:
        extra["training"] = [t.to(case.work or t.dtype) for t in _align_training(
            case.training, case.data, keep.tolist(), case.points.shape[1])]
    case.points = None              # long recordings: hold as few full-length copies as we can
    out, todo = case.out, case.todo     # out: the input, NaN at ``mask`` (within ``unfit``):
    whole = len(keep) == out.shape[1]   # the windows read their input from it, and their
                                        # blended fill is written into it as it comes
    plan = windows.plan(unfit[:, keep].cpu().numpy(), window)
    start = time.perf_counter()
    stds, anchors = {}, {}
    index = {w: k for k, w in enumerate(plan.windows)}
    case.shown = shown = _progress(progress, windows=len(index), method=method)

    def one(a: int, b: int) -> torch.Tensor:
        X = torch.where(unfit[a:b, keep, None], torch.nan, out[a:b, keep])
        part = _fill_window(method, params, extra, X.to(case.work or X.dtype), unfit[a:b, keep],
                            shown, case.info, stds, (a, b), constraints, return_std,
                            index[a, b] + 1, len(index), solve, keep, anchors)
        if len(index) > 1:              # the next window is other data: what this one kept
            clear_kept()                # for a repeat, and its freed temporaries, go back
            clear_rigid_cache()
            trim_heap()
        return part

    def write(a: int, b: int, values: torch.Tensor) -> None:
        """Blended frames, final: into the missing samples of ``out`` (the windows still
        running read frames from ``b`` on)."""
        rows = out[a:b] if whole else out[a:b, keep]
        new = todo[a:b, keep, None] & ~torch.isfinite(rows)
        rows[new] = values[new].to(out.dtype)
        if not whole:
            out[a:b, keep] = rows

    try:
        windows.blend(plan, unfit[:, keep], one, emit=write,
                      workers=1 if out.device.type != "cpu" else workers)
    except BaseException:
        shown.close()                           # no half-drawn bar before the error line
        raise
    case.info.update(seconds=time.perf_counter() - start, windows=len(plan.windows))
    std = case.std
    if len(stds) == len(plan.windows):      # every window has an estimate
        part = windows.blend(plan, unfit[:, keep], lambda a, b: stds[a, b][..., None])[..., 0]
        std[:, keep] = torch.where(todo[:, keep], part.to(std), std[:, keep])
    if len(anchors) == len(plan.windows):
        part = windows.blend(plan, unfit[:, keep], lambda a, b: anchors[a, b][..., None].float())
        case.anchored = torch.zeros_like(todo)
        case.anchored[:, keep] = todo[:, keep] & (part[..., 0] > 0.5)


def _finish(case: _Case, constraints: bool, extrapolate, reject, max_gap, return_std: bool):
    """The post-step, the rejection and ``max_gap`` on the fill; the result as ``fill()`` gives
    it."""
    out, todo, data, info, std = case.out, case.todo, case.data, case.info, case.std
    if constraints and bool(todo.any()):
        case.shown.post_step()
        trim_heap(out.element_size() * out.numel())     # the fits' freed memory goes back
        out, info["constraints"] = _constrain(out, case.own, case.unfit, data, extrapolate,
                                              case.seg_idx, case.solver.spatial,
                                              case.anchored)
        if extrapolate is not None:
            tested = std if case.placed is None else std.masked_fill(case.placed, float("nan"))
            info["untested"] = _leave_untested(out, tested, case.missing, data)
            if case.seg_idx:
                info["alone"] = _leave_alone(out, std, case.missing, data, case.seg_idx)
        if reject is not None and isinstance(data, MarkerSequence):
            info["rejected"] = _reject(out, std, case.missing, data.units, reject)
        if case.method == "auto":
            out, std = _short_gaps_and_bound(out, std, case, info)
    if bool(todo.any()):
        case.shown.close(f"{case.method} filled {int(todo.sum())} samples ({info['windows']} "
                         f"window(s), {info['n_iter']} iterations)")
    if max_gap is not None:
        out = _unfill_long_gaps(out, case.given, case.missing, max_gap)
    result = _as_kind(out, case.kind, data, info, case.missing)
    if not return_std:
        return result
    std = torch.where(torch.isfinite(out).all(dim=2) & case.missing, std, float("nan"))
    if case.kind == "tensor":
        return result, std
    if case.kind == "sequence":
        result.meta["std"] = std.cpu().numpy()
    return result, std.cpu().numpy()


def _warn_never(data, never: torch.Tensor) -> None:
    warnings.warn(f"{int(never.sum())} marker(s) never observed, left unfilled: "
                  f"{_marker_names(data, never)}", UnfilledWarning, stacklevel=5)


def _place_from_training(case: _Case) -> None:
    """Markers never observed in the recording but seen in the training recordings (a marker
    that fell off, or was not placed, in this trial): rebuilt in every frame with three or more
    segment-mates observed, from the local coordinates the training frames show (the rigid
    reconstruction of :func:`torchfill.solvers.rigid.segment_fill` on the recording's observed
    frames stacked with the training's), where its own error estimate is as small as ``auto``
    asks of its rigid candidate (``PARTIAL``); the estimate comes with the fill. The rest stays
    NaN (cmu_85_02 under numediart_03_rolling's mask, cmu_85_12 as training: RMT5 placed at a
    median 21 mm; RWRA, whose forearm segment bends at the wrist, at 108 mm with an estimate of
    179 mm, left NaN)."""
    out, J = case.out, case.out.shape[1]
    if case.seg_idx and out.shape[2] == 3:
        train = _align_training(case.training, case.data, list(range(J)), J)
        train = [spread_runs(t, TRAINING_FRAMES // len(train)) for t in train]
        P = torch.where(case.unfit[..., None], float("nan"), out).double().cpu()
        apart = torch.full((HOLDOUT_LAGS[-1], *P.shape[1:]), float("nan"), dtype=P.dtype)
        S = torch.cat([P, apart, *train]).numpy()   # another trial is far in time: its error too
        est, std, _ = segment_fill(S, None, case.seg_idx)
        T = out.shape[0]
        limit = PARTIAL["rigid"]["max_error"] * body_size(S[:T], np.isfinite(S[:T]).all(axis=2))
        put = np.sqrt(3.0) * np.nan_to_num(std[:T], nan=np.inf) <= limit   # as auto's rigid
        put &= case.never.cpu().numpy()[None, :]
        case.placed = torch.from_numpy(put).to(out.device)
        out[case.placed] = torch.from_numpy(est[:T][put]).to(out)
        case.std[case.placed] = torch.from_numpy(std[:T][put]).to(case.std)
        case.todo = case.todo | case.placed
        if case.shown is None:                          # nothing else was missing
            case.shown = _progress(False, windows=0, method=case.method)
    left = case.never & ~torch.isfinite(out).all(dim=2).any(dim=0)
    if bool(left.any()):
        _warn_never(case.data, left)


def _solver_params(method: str, params: dict | None, training, legacy: dict,
                   window_given: bool) -> tuple[dict, object]:
    """The method's hyperparameters from ``params`` (and, deprecated, ``fill()``'s extra keyword
    arguments), checked against ``fill()``'s own arguments; and the training data."""
    if params is not None and not isinstance(params, dict):
        raise ValueError(f"params expected a dict of hyperparameters, found {type(params).__name__}")
    params = dict(params or {})
    if legacy:
        both = sorted(set(legacy) & set(params))
        if both:
            raise ValueError(f"{', '.join(both)} given both in params and as keyword arguments")
        if set(legacy) - {"training"}:
            warnings.warn(f"fill(): method hyperparameters as keyword arguments "
                          f"({', '.join(sorted(set(legacy) - {'training'}))}) are deprecated and "
                          f"will be removed in the next release; pass params={{...}}",
                          DeprecationWarning, stacklevel=3)
        params.update(legacy)
    if "training" in params:
        if training is not None:
            raise ValueError("training given twice (as fill()'s training and in params)")
        training = params.pop("training")
    declared = get_solver(method).declared_params() if method in available() else {}
    if window_given and "window" in declared and "window" not in params:
        raise ValueError(f"window is both fill()'s (frames solved at once) and a hyperparameter "
                         f"of {method} ({declared['window'].doc}); give {method}'s in params "
                         f"(params={{'window': ...}}; CLI: -p window=...), and name it there too "
                         f"to set only fill()'s")
    return params, training


def _fill_batch(data, mask, again):
    """A batch ``(B, T, J, D)``: one fill per sequence, stacked (std too, with ``return_std``)."""
    tensor = isinstance(data, torch.Tensor)
    if mask is not None and len(mask) != len(data):
        raise ValueError(f"a batch of {len(data)} sequences expected a mask (B, T, J) with B = "
                         f"{len(data)}, found {len(mask)} masks")
    done = [again(data[b], mask=None if mask is None else mask[b]) for b in range(len(data))]
    stack = torch.stack if tensor else np.stack
    if isinstance(done[0], tuple):
        return tuple(stack([d[k] for d in done]) for k in range(len(done[0])))
    return stack(done)


def _previous_fill(data, mask) -> np.ndarray | None:
    """``(T, J)`` samples of a MarkerSequence that an earlier fill made (``meta["filled"]``: set
    by ``fill()``, and by the readers from the file's own mark), still finite and not in ``mask``;
    None when there are none."""
    filled = data.meta.get("filled") if isinstance(data, MarkerSequence) else None
    if filled is None or np.shape(filled) != data.points.shape[:2]:
        return None
    prior = np.asarray(filled, dtype=bool) & np.isfinite(data.points).all(axis=2)
    if mask is not None and np.shape(mask) == prior.shape:
        prior &= ~np.asarray(mask, dtype=bool)
    return prior if prior.any() else None


def _refill(data: MarkerSequence, prior: np.ndarray, method, *, return_std: bool, **kwargs):
    """Fill ``data`` as if its earlier fills (``prior``) were gaps, then put those samples back
    as they were: they are kept, but never fitted to nor extrapolated from, so that filling a
    filled recording again gives the same recording (the method sees the same observed samples
    and leaves the same samples unfilled)."""
    bare = data.with_points(np.where(prior[..., None], np.nan, data.points))
    bare.meta.pop("filled", None)
    bare.meta.pop("std", None)
    result = fill(bare, method, return_std=return_std, **kwargs)
    out, std = result if return_std else (result, None)
    out.points[prior] = data.points[prior]
    meet_kept(out.points, out.meta["filled"] & ~prior, prior)
    out.meta["filled"] = out.meta["filled"] | prior
    if std is None:
        return out
    old = data.meta.get("std")
    if old is not None and np.shape(old) == prior.shape:
        std[prior] = np.asarray(old)[prior]
    out.meta["std"] = std
    return out, std


def _work_dtype(dtype, solver) -> torch.dtype | None:
    """The dtype a method computes in: ``dtype`` (a torch dtype or its name), else the solver's
    ``fill_dtype`` (None: the data's own)."""
    if dtype is None:
        return solver.fill_dtype
    found = getattr(torch, dtype, None) if isinstance(dtype, str) else dtype
    if found not in (torch.float32, torch.float64):
        raise ValueError(f"dtype expected 'float32' or 'float64', found {dtype!r}")
    return found


#: An observed coordinate farther than this many spreads (median absolute deviation of all
#: coordinates) from their median is taken for corrupt: it would dominate the solvers' shared
#: centring and scaling (at ~1e34 every fill cancels to 0).
HUGE_SPREADS = 1e6


def _huge(points: torch.Tensor, missing: torch.Tensor) -> torch.Tensor:
    """``(T, J)`` observed samples with a coordinate beyond ``HUGE_SPREADS``; they stay in the
    output as they were but the fit does not see them (one warning says how many)."""
    seen = points[~missing]
    if seen.numel() == 0:
        return torch.zeros_like(missing)
    med = seen.median()
    spread = max(float((seen - med).abs().median()), 1e-3 * abs(float(med)), 1e-300)
    huge = ((points - med).abs() > HUGE_SPREADS * spread).any(dim=2) & ~missing
    if bool(huge.any()):
        t, j = (int(i) for i in torch.nonzero(huge)[0])
        warnings.warn(f"{int(huge.sum())} observed sample(s) with huge coordinates (more than "
                      f"{HUGE_SPREADS:g} x the data's spread from its median; first: frame {t}, "
                      f"marker {j}) kept as they are but not used for the fit",
                      UserWarning, stacklevel=5)
    return huge


def _segment_indices(segments, data, points: torch.Tensor, unfit: torch.Tensor) -> dict:
    """The segments in use as ``name -> marker indices`` (see :mod:`torchfill.segments`)."""
    from .solvers.rigid import index_segments

    labels = list(data.labels) if isinstance(data, MarkerSequence) else None
    X = torch.where(unfit[..., None], torch.nan, points).cpu().numpy()
    return index_segments(segments, labels, X, ~unfit.cpu().numpy())


def _constrain(out: torch.Tensor, own: torch.Tensor, missing: torch.Tensor, data, extrapolate,
               segments=None, spatial: bool = False, anchored: torch.Tensor | None = None):
    """The constraints post-step on the fill; coordinates the input had stay bit-for-bit.
    ``spatial``: the method places markers from the same frame (see ``Solver.spatial``);
    ``anchored``: fills the soft distances do not move (see :func:`constrain`)."""
    rate = data.rate if isinstance(data, MarkerSequence) else None
    frames = None if extrapolate is None or not rate else int(round(extrapolate * rate))
    names = data.labels if isinstance(data, MarkerSequence) else None
    F, report = constrain(out.cpu().numpy(), missing.cpu().numpy(), extrapolate=frames,
                          long=int(LONG_GAP_SECONDS * rate) if rate else None, names=names,
                          segments=segments, spatial=spatial,
                          anchored=None if anchored is None else anchored.cpu().numpy())
    new = torch.as_tensor(F, dtype=out.dtype, device=out.device)
    return torch.where(own, out, new), report


def _progress(progress, **kw):
    """The fill's progress object (:func:`torchfill.progress.make`; imported only when used)."""
    if progress is None or progress is False:
        from .progress import Silent     # light: no tqdm
        return Silent()
    from .progress import make
    return make(progress, **kw)


def _fill_window(method: str, params: dict, extra: dict, X: torch.Tensor, missing: torch.Tensor,
                 progress, info: dict,
                 stds: dict | None = None, key: tuple[int, int] = (0, 0),
                 constraints: bool = True, holdout: bool = False, window: int = 1,
                 windows: int = 1, solve: Callable | None = None,
                 markers: torch.Tensor | None = None, anchors: dict | None = None
                 ) -> torch.Tensor:
    """Solve one window: a fresh solver fitted to ``X`` (NaN where ``missing``; ``extra``: fit
    data such as ``training``); returns its fill and adds its iterations to ``info``. Per-window
    steps (``auto``'s choice) belong here; the constraints run once, on the whole recording.
    ``stds``: a dict that receives the window's error estimate (T, J) under its frame range (the
    solver's ``std_`` -- ``auto`` -- or the method's hold-out error by gap kind)."""
    solver = get_solver(method, **params)
    where = {"window": window, "windows": windows, "max_iter": solver.max_iter}
    (solve or _fit)(solver, X, missing, extra, lambda d: progress.update({**where, **d}),
                    (slice(*key), markers))
    filled = solver.transform(X)
    progress.window_done(window, solver.n_iter_)
    with _LOCK:                                 # windows may be solved in threads
        params.update(solver.carry())           # the next window reuses what this one chose
        info["n_iter"] += solver.n_iter_
    est = getattr(solver, "std_", None)
    if stds is not None and (est is not None or holdout):
        if est is None:
            est = holdout_std(method, params, X, missing, seed=solver.seed,
                              post=constrain_candidates if constraints else None, **extra)
        stds[key] = est.to(filled.dtype)
    if anchors is not None and getattr(solver, "anchored_", None) is not None:
        anchors[key] = solver.anchored_
    return filled


def _fit(solver, X: torch.Tensor, missing: torch.Tensor, data: dict, callback, part) -> None:
    """The default ``solve`` of :func:`fill_case`: the solver's own loop."""
    solver.fit(X, missing, callback=callback, **data)


def holdout_std(method: str, params: dict, X: torch.Tensor, missing: torch.Tensor, seed: int = 0,
                post=None, **data) -> torch.Tensor:
    """Error estimate (T, J) for a fill by ``method`` (one that has no own): ``auto`` run with that
    method as its only candidate, i.e. the method's held-out error on gaps of each kind.
    ``data``: the method's fit data (``training=``); ``post``: the post-step, as fill()'s."""
    solver = get_solver("auto", candidates=(method,), candidate_params={method: dict(params)},
                        seed=seed)
    solver.fit(X, missing, post=post, **data)
    return solver.std_


def _align_training(training, data, keep: list[int], n_markers: int) -> list[torch.Tensor]:
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
            item = _matched(item, data, [labels[j] for j in keep])
        else:
            item = np.asarray(item.detach().cpu() if isinstance(item, torch.Tensor) else item,
                              dtype=np.float64)
            if item.ndim != 3 or item.shape[1:] != (n_markers, D):
                raise ValueError(f"training array expected shape (T, {n_markers}, {D}) like the "
                                 f"recording to fill, found {item.shape}")
            item = item[:, keep]
        aligned.append(torch.from_numpy(np.array(item, dtype=np.float64)))
    return aligned


def _matched(item: MarkerSequence, data: MarkerSequence, names: list[str]) -> np.ndarray:
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
    points *= per_mm(data.units) / per_mm(item.units)
    if item.rate and data.rate and abs(item.rate - data.rate) > 1e-9 * data.rate:
        T = max(1, int(round(item.n_frames * data.rate / item.rate)))
        frames = np.minimum(np.round(np.arange(T) * item.rate / data.rate).astype(int),
                            item.n_frames - 1)
        points = points[frames]
    return points


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
    if X.ndim != 3 or X.shape[2] < 1:
        raise ValueError(f"expected marker data of shape (T, J, D) (D = 3: xyz, 2: image "
                         f"keypoints), found {tuple(X.shape)}")
    if X.shape[0] < 2 or X.shape[1] < 1:
        raise ValueError(f"expected at least 2 frames and 1 marker, found {tuple(X.shape)}")
    if bool(torch.isinf(X).any()):
        raise ValueError("marker data contains infinite values; use NaN for missing samples")
    return X, kind


def _as_kind(out: torch.Tensor, kind: str, data, info: dict, missing: torch.Tensor):
    if kind == "tensor":
        return out
    points = out.cpu().numpy()
    if kind == "array":
        return points
    seq = data.with_points(points)
    seq.meta["filled"] = missing.cpu().numpy() & np.isfinite(points).all(axis=2)  # mask= too
    seq.meta["fill_info"] = info
    return seq


def _short_gaps_and_bound(out: torch.Tensor, std: torch.Tensor, case: _Case, info: dict):
    """The default's short interior gaps kept on the interpolation across them where its fill
    departs from it, and its estimate bounded by what the fill can be off
    (:mod:`torchfill.qc.finish`); observed coordinates stay bit for bit."""
    data = case.data
    X = torch.where(case.missing[..., None], float("nan"), out).cpu().numpy()
    seq = isinstance(data, MarkerSequence)
    F, changed = short_gap_fallback(X, out.cpu().numpy(), data.rate if seq else None,
                                    per_mm(data.units if seq else "mm", X.shape[2]))
    info["short_gaps"] = len(changed)
    if changed:
        out = torch.where(case.own, out, torch.as_tensor(F, dtype=out.dtype, device=out.device))
    bound = torch.as_tensor(std_bound(X, F), dtype=std.dtype, device=std.device)
    return out, torch.minimum(std, bound)


def _reject(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor, units: str,
            limit_mm: float) -> int:
    """Leave NaN the filled samples whose estimated 3-D error (sqrt(3) x the per-coordinate std)
    is above ``limit_mm`` -- at a trial end from the first such sample to the end of the trial,
    inside a trial the whole gap when its RMS estimate is above it; returns how many were left NaN
    (one warning says how many)."""
    if str(units).strip().lower() not in ("mm", "cm", "m") or not bool(torch.isfinite(std).any()):
        return 0                                    # e.g. pixels: no threshold in mm
    scale = 1.0 / per_mm(units)
    T = out.shape[0]
    err = (3.0 ** 0.5 * std * scale).cpu().numpy()
    count = 0
    for j, a, b in gap_runs(missing.cpu().numpy()):         # the gaps, parts left NaN or not
        e = np.nan_to_num(err[a:b, j], nan=0.0)
        bad = np.flatnonzero(e > limit_mm)
        if bad.size == 0:
            continue
        if a == 0 and b < T:                        # trial start: far part, up to the worst
            drop = slice(a, a + int(bad.max()) + 1)
        elif b == T and a > 0:                      # trial end: from the first bad to the end
            drop = slice(a + int(bad.min()), b)
        elif float(np.sqrt(np.mean(e ** 2))) > limit_mm:
            drop = slice(a, b)
        else:
            continue
        count += int(torch.isfinite(out[drop, j]).all(dim=1).sum())     # not those already NaN
        out[drop, j] = float("nan")
    if count:
        warnings.warn(f"{count} filled sample(s) left unfilled: their estimated error is above "
                      f"{limit_mm:g} mm (reject=None fills them)", UnfilledWarning,
                      stacklevel=5)
    return count


def _leave_untested(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor, data) -> int:
    """Leave NaN the filled samples :func:`torchfill.qc.untested` names (markers never seen in two
    consecutive frames; only where the fill has an error estimate); returns how many, with one
    warning naming the markers."""
    drop = torch.as_tensor(untested(missing.cpu().numpy(), std.cpu().numpy()), device=out.device)
    return _leave_nan(out, drop & torch.isfinite(out).all(dim=2), data,
                      "never seen in two consecutive frames, so neither the fill nor its error "
                      "estimate has observed motion to go on")


def _leave_alone(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor, data,
                 segments: dict) -> int:
    """Leave NaN the filled samples :func:`torchfill.qc.alone` names (markers whose segment-mates
    are never observed, estimate above the QC's check level); returns how many, with one warning
    naming the markers."""
    units = data.units if isinstance(data, MarkerSequence) else "mm"
    drop = torch.as_tensor(alone(torch.isfinite(out).all(dim=2).cpu().numpy(),
                                 missing.cpu().numpy(), std.cpu().numpy(), segments, units),
                           device=out.device)
    return _leave_nan(out, drop, data,
                      f"no other marker of their segment is ever observed and their estimated "
                      f"error is above {EST_CHECK_MM:g} mm, so the fill alone would pose the "
                      f"segment")


def _leave_nan(out: torch.Tensor, drop: torch.Tensor, data, why: str) -> int:
    """Set the (T, J) samples ``drop`` of ``out`` to NaN; one UnfilledWarning says how many, of
    which markers, and ``why``. Returns how many."""
    count = int(drop.sum())
    if count:
        out[drop] = float("nan")
        which = drop.any(dim=0)
        warnings.warn(f"{count} filled sample(s) of {int(which.sum())} marker(s) left NaN: {why} "
                      f"({_marker_names(data, which, 8)}; extrapolate=None fills them)",
                      UnfilledWarning, stacklevel=6)
    return count


def _unfill_long_gaps(out: torch.Tensor, given: torch.Tensor, missing: torch.Tensor,
                      max_gap: int) -> torch.Tensor:
    """Put the long gaps back as they were given (NaN, except finite coordinates of a sample
    that was only partly missing: those are observed and stay)."""
    long = [(j, a, b) for j, a, b in gap_runs(missing.cpu().numpy()) if b - a > max_gap]
    for j, a, b in long:
        out[a:b, j] = given[a:b, j]
    if long:
        warnings.warn(f"{len(long)} gap(s) longer than max_gap={max_gap} frames left unfilled",
                      UnfilledWarning, stacklevel=5)
    return out


def _marker_names(data, which: torch.Tensor, most: int | None = None) -> str:
    idx = torch.nonzero(which).flatten().tolist()
    names = [data.labels[i] for i in idx] if isinstance(data, MarkerSequence) else list(map(str, idx))
    more = most is not None and len(names) > most
    return ", ".join(names[:most] if more else names) + (" ..." if more else "")
