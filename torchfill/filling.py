"""``fill()``: the one entry point that validates input, runs a registered solver and returns the
same kind of object it was given, observed samples bit-for-bit unchanged. It knows the solver
contract only (the registry, declared hyperparameters and fit data); the options are
:class:`torchfill.options.FillOptions`."""
from __future__ import annotations

import inspect
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import MISSING, dataclass, fields

import numpy as np
import torch

from . import unfilled, windows
from .constraints import CandidatePost, constrain, meet_kept
from .options import DEFAULT_METHODS, OPTIONS_DOC, FillOptions, default_method, work_dtype
from .runtime.cache import clear_all as clear_kept
from .runtime.memory import trim_heap
from .windows import holdout_std  # noqa: F401 (a public name of this module)
from .kinds import as_kind, as_tensor, recordings
from .sequence import MarkerSequence
from .solvers import available, get_solver, index_segments, place_from_training
from .training import align_training
from .unfilled import UnfilledWarning

_LOCK = threading.Lock()

#: Gaps longer than this (seconds) filled without rigid donors are named in a warning.
LONG_GAP_SECONDS = 10.0

__all__ = ["DEFAULT_METHODS", "FillOptions", "UnfilledWarning", "default_method", "fill",
           "fill_case", "holdout_std", "methods"]


def methods() -> list[str]:
    """The registered method names."""
    return available()


def fill(data, method: str | None = None, *, options: FillOptions | None = None, **keywords):
    """Fill the gaps of a recording.

    Parameters
    ----------
    data : MarkerSequence, ndarray or torch.Tensor of shape (T, J, D), or a batch (B, T, J, D)
        D = 3 (markers, xyz) or 2 (image keypoints, xy); any D >= 1 for arrays and tensors. NaN
        marks a missing coordinate; a sample with any NaN coordinate counts as missing. A batch
        of arrays or tensors is filled sequence by sequence (``mask`` then ``(B, T, J)``) and
        returned as a batch; a list (or tuple) of recordings is filled one by one, each alone
        (lengths and markers may differ; ``mask`` then a list too), and returned as a list (tuple).
        A tensor that requires grad is refused: no fill is differentiable with respect to its
        input. float16 / bfloat16 tensors are computed in float32 and returned in
        their own dtype.
    method : str, optional
        A name from :func:`methods` (default: the best registered, see ``DEFAULT_METHODS``).
    {options}
    options : FillOptions, optional
        All of the above in one object (the keywords given as well override its fields).
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
    if options is not None:
        keywords = {**options.keywords(), **keywords}
        method = options.method if method is None else method
    opts = FillOptions.make(method, **keywords)
    if recordings(data):
        return _fill_each(data, opts)
    prior = _previous_fill(data, opts.mask)
    if prior is not None:
        return _refill(data, prior, opts)
    if not isinstance(data, MarkerSequence) and np.ndim(data) == 4:
        return _fill_batch(data, opts)
    if isinstance(data, torch.Tensor) and data.dtype in (torch.float16, torch.bfloat16):
        # computed in float32; every float16/bfloat16 value is exact in float32 and back
        done = fill(data.float(), options=opts)
        return tuple(d.to(data.dtype) for d in done) if opts.return_std else done.to(data.dtype)
    return fill_case(data, opts)


def _signature() -> inspect.Signature:
    """``fill()``'s signature as ``help()`` shows it: every option of :class:`FillOptions`."""
    P = inspect.Parameter
    opts = [P(f.name, P.KEYWORD_ONLY, default=f.default if f.default is not MISSING else
              f.default_factory(), annotation=f.type)
            for f in fields(FillOptions) if f.name != "method"]
    return inspect.Signature([P("data", P.POSITIONAL_OR_KEYWORD),
                              P("method", P.POSITIONAL_OR_KEYWORD, default=None,
                                annotation="str | None"),
                              *opts, P("options", P.KEYWORD_ONLY, default=None,
                                       annotation="FillOptions | None"),
                              P("legacy", P.VAR_KEYWORD)])


fill.__signature__ = _signature()
fill.__doc__ = fill.__doc__.replace("    {options}\n", OPTIONS_DOC)


def fill_case(data, options: FillOptions, solve: Callable | None = None):
    """Fill one recording ``(T, J, D)`` with checked ``options``: prepare -> solve -> finish.

    The one path of a fill: :func:`fill` calls it once it has checked its arguments (and split a
    batch, widened half precision, set earlier fills aside), and the experiment runner
    (:mod:`torchfill.lightning.runner`) calls it for every case, so that an experiment scores what
    ``fill()`` returns; the papers' protocols are options (``constraints=False``,
    ``extrapolate=None``, ``window=None``, ``dtype``). The result is :func:`fill`'s; and

    solve : callable, optional
        ``solve(solver, X, missing, data, callback, part)`` fits ``solver`` to one window ``X``
        (NaN where ``missing``; ``data``: its fit data such as ``training``; ``callback``: takes
        each iteration's record; ``part``: ``(frames, markers)``, the window's frame slice and
        marker indices in ``data``) as ``solver.fit`` does -- the default; the runner drives the
        same solver under a Lightning Trainer, one ``step()`` per training step.
    """
    case = _prepare(data, options)
    if bool(case.todo.any()):
        _solve(case, options, solve)
    if case.training is not None and bool(case.never.any()):
        _place_from_training(case)
    return _finish(case, options)


@dataclass
class _Case:
    """A recording on its way through :func:`fill_case` (tensors ``(T, J, D)`` / ``(T, J)``)."""

    data: object                     # what the caller gave (labels, rate, units, kind)
    kind: str                        # "sequence", "array" or "tensor"
    method: str
    params: dict                     # the method's hyperparameters (with what windows carry)
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


def _prepare(data, o: FillOptions) -> _Case:
    """Validate the method and data, and find what is missing, what the solver may see and the
    segments."""
    method, params, training, mask = o.method, dict(o.params), o.training, o.mask
    solver = get_solver(method, **params)                           # validate early
    work = work_dtype(o.dtype, solver)
    if training is not None and "training" not in solver.fit_data:
        raise ValueError(f"{method}: takes no training data; methods that do: "
                         f"{', '.join(m for m in methods() if 'training' in get_solver(m).fit_data)}")
    points, kind = as_tensor(data)
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
        unfilled.warn_never(data, never)
    todo = missing & ~never
    info = {"method": method, "n_iter": 0, "seconds": 0.0, "windows": 0,
            "dtype": str(work or points.dtype).removeprefix("torch.")}
    seg_idx = None
    if (bool(todo.any()) or training is not None) and points.shape[2] == 3 and (
            o.constraints or o.segments is not None or "segments" in solver.fit_data):
        seg_idx = _segment_indices(o.segments, data, points, unfit)
    return _Case(data, kind, method, params, solver, work, points, out,
                 out.clone() if o.max_gap is not None else None, torch.isfinite(out), missing, unfit, never,
                 todo, training, seg_idx, info,
                 torch.full(missing.shape, float("nan"), dtype=out.dtype, device=out.device))


def _solve(case: _Case, o: FillOptions, solve: Callable | None) -> None:
    """Solve the markers observed somewhere, window by window (:mod:`torchfill.windows`; the
    later ones in worker processes where that pays and ``solve`` is the default), and write
    their fill (and error estimate) into ``case``."""
    keep = torch.nonzero(~case.never).flatten()
    extra = _fit_data(case, o, keep)
    case.points = None              # long recordings: hold as few full-length copies as we can
    unfit, todo = case.unfit[:, keep], case.todo[:, keep]
    plan = windows.plan(unfit.cpu().numpy(), o.window)
    start = time.perf_counter()
    case.shown = _progress(o.progress, windows=len(plan.windows), method=case.method)
    run = _Windows(case, windows.Job(case.method, case.params, extra, len(plan.windows), keep,
                                     o.return_std, o.constraints), plan, solve)
    relay = o.progress is not None and o.progress is not False
    remote = None if solve is not None or case.out.device.type != "cpu" else windows.Remote(
        lambda a, b: (run.job, *run.cut(a, b), (a, b), run.number(a, b), relay), run.done,
        case.shown.update)
    try:
        windows.blend(plan, unfit, run.one, emit=run.write, remote=remote,
                      workers=1 if case.out.device.type != "cpu" else o.workers)
    except BaseException:
        case.shown.close()                      # no half-drawn bar before the error line
        raise
    case.info.update(seconds=time.perf_counter() - start, windows=len(plan.windows))
    std, stds, anchors = case.std, run.stds, run.anchors
    if len(stds) == len(plan.windows):      # every window has an estimate
        part = windows.blend(plan, unfit, lambda a, b: stds[a, b][..., None])[..., 0]
        std[:, keep] = torch.where(todo, part.to(std), std[:, keep])
    if len(anchors) == len(plan.windows):
        part = windows.blend(plan, unfit, lambda a, b: anchors[a, b][..., None].float())
        case.anchored = torch.zeros_like(case.todo)
        case.anchored[:, keep] = todo & (part[..., 0] > 0.5)


def _fit_data(case: _Case, o: FillOptions, keep: torch.Tensor) -> dict:
    """The fit data the solver declares (segments, the post-step, training) for markers ``keep``."""
    kept_segments = None
    if case.seg_idx is not None:
        at = {int(j): i for i, j in enumerate(keep.tolist())}
        kept_segments = {s: [at[j] for j in m if j in at] for s, m in case.seg_idx.items()}
    takes, extra = case.solver.fit_data, {}
    if kept_segments is not None and "segments" in takes:
        extra["segments"] = kept_segments
    if o.constraints and "post" in takes:                 # auto scores fills as they come out
        extra["post"] = CandidatePost(kept_segments)
    if case.training is not None:
        extra["training"] = [t.to(case.work or t.dtype) for t in align_training(
            case.training, case.data, keep.tolist(), case.points.shape[1])]
    return extra


class _Windows:
    """The windows of one fill: each reads its input from ``case.out`` (the input, NaN at
    ``mask``), and the blended fill is written back into it as frames become final."""

    def __init__(self, case: _Case, job: windows.Job, plan: windows.Plan, solve) -> None:
        self.case, self.job, self.solve = case, job, solve
        self.index = {w: k + 1 for k, w in enumerate(plan.windows)}
        self.keep, self.whole = job.markers, len(job.markers) == case.out.shape[1]
        self.stds, self.anchors, self.warned = {}, {}, {}

    def number(self, a: int, b: int) -> int:
        return self.index[a, b]

    def cut(self, a: int, b: int) -> tuple[torch.Tensor, torch.Tensor]:
        """A window's input (NaN where the solver does not look) and what it does not see."""
        unfit = self.case.unfit[a:b, self.keep]
        X = torch.where(unfit[..., None], torch.nan, self.case.out[a:b, self.keep])
        return X.to(self.case.work or X.dtype), unfit

    def take(self, a: int, b: int, got: windows.Solved) -> torch.Tensor:
        """A window's fit: its iterations and choice (the next windows reuse it), its error
        estimate and anchors kept for their blends; its fill."""
        self.case.shown.window_done(self.index[a, b], got.n_iter)
        with _LOCK:                                 # windows may be solved in threads
            self.job.params.update(got.carry)
            self.case.info["n_iter"] += got.n_iter
        if got.std is not None:
            self.stds[a, b] = got.std
        if got.anchored is not None:
            self.anchors[a, b] = got.anchored
        return got.fill

    def one(self, a: int, b: int) -> torch.Tensor:
        """A window solved in this process."""
        got = windows.fit(self.job, *self.cut(a, b), (a, b), self.index[a, b],
                          self.case.shown.update, self.solve)
        if len(self.index) > 1:         # the next window is other data: what this one kept
            clear_kept()                # for a repeat, and its freed temporaries, go back
            trim_heap()
        return self.take(a, b, got)

    def done(self, a: int, b: int, result) -> torch.Tensor:
        """A window a worker process solved (:func:`windows.fit_remote`)."""
        got, caught = result
        windows.warn_again(caught, self.warned)
        if isinstance(got, Exception):
            raise got
        return self.take(a, b, got)

    def write(self, a: int, b: int, values: torch.Tensor) -> None:
        """Blended frames, final: into the missing samples of ``out`` (the windows still
        running read frames from ``b`` on)."""
        out, keep = self.case.out, self.keep
        rows = out[a:b] if self.whole else out[a:b, keep]
        new = self.case.todo[a:b, keep, None] & ~torch.isfinite(rows)
        rows[new] = values[new].to(out.dtype)
        if not self.whole:
            out[a:b, keep] = rows


def _finish(case: _Case, o: FillOptions):
    """The post-step, the rejection and ``max_gap`` on the fill; the result as ``fill()`` gives
    it."""
    out, todo, data, info, std = case.out, case.todo, case.data, case.info, case.std
    extrapolate = o.extrapolate
    if o.constraints and bool(todo.any()):
        case.shown.post_step()
        trim_heap(out.element_size() * out.numel())     # the fits' freed memory goes back
        out, info["constraints"] = _constrain(out, case.own, case.unfit, data, extrapolate,
                                              case.seg_idx, case.solver.spatial,
                                              case.anchored)
        if case.solver.finish_short_gaps:       # first: what is left NaN reads the final std
            out, std = unfilled.short_gaps_and_bound(out, std, case.missing, case.own, data,
                                                     info)
        if extrapolate is not None:
            tested = std if case.placed is None else std.masked_fill(case.placed, float("nan"))
            info["untested"] = unfilled.leave_untested(out, tested, case.missing, data)
            if case.seg_idx:
                info["alone"] = unfilled.leave_alone(out, std, case.missing, data,
                                                      case.seg_idx)
        if o.reject is not None and isinstance(data, MarkerSequence):
            info["rejected"] = unfilled.reject(out, std, case.missing, data.units, o.reject)
    if bool(todo.any()):
        case.shown.close(f"{case.method} filled {int(todo.sum())} samples ({info['windows']} "
                         f"window(s), {info['n_iter']} iterations)")
    if o.max_gap is not None:
        out = unfilled.unfill_long_gaps(out, case.given, case.missing, o.max_gap)
    result = as_kind(out, case.kind, data, info, case.missing)
    if not o.return_std:
        return result
    std = torch.where(torch.isfinite(out).all(dim=2) & case.missing, std, float("nan"))
    if case.kind == "tensor":
        return result, std
    if case.kind == "sequence":
        result.meta["std"] = std.cpu().numpy()
    return result, std.cpu().numpy()


def _place_from_training(case: _Case) -> None:
    """Markers never observed in the recording but seen in the training recordings: placed from
    their segment-mates where the rigid fill's own error estimate is small
    (:func:`torchfill.solvers.placement.place_from_training`), estimate included; the rest stays
    NaN with a warning."""
    out, J = case.out, case.out.shape[1]
    if case.seg_idx and out.shape[2] == 3:
        train = align_training(case.training, case.data, list(range(J)), J)
        P = torch.where(case.unfit[..., None], float("nan"), out)
        case.placed, est, std = place_from_training(P, case.never, train, case.seg_idx)
        out[case.placed] = est[case.placed].to(out)
        case.std[case.placed] = std[case.placed].to(case.std)
        case.todo = case.todo | case.placed
        if case.shown is None:                          # nothing else was missing
            case.shown = _progress(False, windows=0, method=case.method)
    left = case.never & ~torch.isfinite(out).all(dim=2).any(dim=0)
    if bool(left.any()):
        unfilled.warn_never(case.data, left)


def _fill_each(data, o: FillOptions):
    """A list or tuple of recordings: each filled alone (lengths and markers may differ), the
    same kind of container back (with ``return_std``, one of fills and one of stds)."""
    mask = o.mask
    if mask is not None and (not isinstance(mask, (list, tuple)) or len(mask) != len(data)):
        raise ValueError(f"a list of {len(data)} recordings expected a list of {len(data)} masks, "
                         f"found {type(mask).__name__}")
    done = []
    for i, item in enumerate(data):
        try:
            done.append(fill(item, options=o.replace(mask=None if mask is None else mask[i])))
        except ValueError as err:
            raise ValueError(f"data[{i}]: {err}") from None
    if isinstance(done[0], tuple):
        return type(data)(d[0] for d in done), type(data)(d[1] for d in done)
    return type(data)(done)


def _fill_batch(data, o: FillOptions):
    """A batch ``(B, T, J, D)``: one fill per sequence, stacked (std too, with ``return_std``)."""
    tensor, mask = isinstance(data, torch.Tensor), o.mask
    if mask is not None and len(mask) != len(data):
        raise ValueError(f"a batch of {len(data)} sequences expected a mask (B, T, J) with B = "
                         f"{len(data)}, found {len(mask)} masks")
    done = [fill(data[b], options=o.replace(mask=None if mask is None else mask[b]))
            for b in range(len(data))]
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


def _refill(data: MarkerSequence, prior: np.ndarray, o: FillOptions):
    """Fill ``data`` as if its earlier fills (``prior``) were gaps, then put those samples back
    as they were: they are kept, but never fitted to nor extrapolated from, so that filling a
    filled recording again gives the same recording (the method sees the same observed samples
    and leaves the same samples unfilled)."""
    bare = data.with_points(np.where(prior[..., None], np.nan, data.points))
    bare.meta.pop("filled", None)
    bare.meta.pop("std", None)
    result = fill(bare, options=o)
    out, std = result if o.return_std else (result, None)
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
    med = _lower_median(seen)
    spread = max(float(_lower_median((seen - med).abs())), 1e-3 * abs(float(med)), 1e-300)
    huge = ((points - med).abs() > HUGE_SPREADS * spread).any(dim=2) & ~missing
    if bool(huge.any()):
        t, j = (int(i) for i in torch.nonzero(huge)[0])
        warnings.warn(f"{int(huge.sum())} observed sample(s) with huge coordinates (more than "
                      f"{HUGE_SPREADS:g} x the data's spread from its median; first: frame {t}, "
                      f"marker {j}) kept as they are but not used for the fit",
                      UserWarning, stacklevel=5)
    return huge


def _lower_median(x: torch.Tensor) -> torch.Tensor:
    """``x.median()`` (the lower middle value of an even count) by a partial sort on the CPU:
    one value is selected, not the whole tensor sorted."""
    if x.device.type != "cpu":
        return x.median()
    flat = x.detach().reshape(-1).numpy()
    k = (flat.size - 1) // 2
    return torch.as_tensor(np.partition(flat, k)[k], dtype=x.dtype)


def _segment_indices(segments, data, points: torch.Tensor, unfit: torch.Tensor) -> dict:
    """The segments in use as ``name -> marker indices`` (see :mod:`torchfill.segments`)."""
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
