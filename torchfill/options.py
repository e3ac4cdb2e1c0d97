"""``fill()``'s options: one definition of each (name, default, check), checked once.

:class:`FillOptions` is what :func:`torchfill.fill` builds from its keywords, and what the command
line, the batch runner and the experiment runner build and pass on; :func:`torchfill.filling.fill_case`
takes it checked. Importing this module imports no torch (the command line checks its
arguments before torch is loaded).
"""
from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

from ._catalog import resolve



#: Default window length in frames (chosen on accuracy and speed, see the README's "Long
#: recordings"); :mod:`torchfill.windows` cuts long recordings in windows of this length.
WINDOW = 6000


class _Default(int):
    """The default of an ``int`` option, told apart from the same number given explicitly."""


#: Names of the dtypes a method may compute in.
DTYPES = ("float32", "float64")


@dataclass(frozen=True)
class FillOptions:
    """How to fill: the method, its hyperparameters and ``fill()``'s own options. Build it with
    :meth:`make` (checks and normalises) or construct it and call :meth:`checked`.

    Parameters
    ----------
    method : str, optional
        A name from :func:`torchfill.methods` (default: the best registered, see
        ``DEFAULT_METHODS``).
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
        Windows solved at once, each on its share of torch's intra-op threads (default and most:
        that thread count, ``torch.get_num_threads()``, and the cores; on CPU only): in worker
        processes where a long recording has two or more later windows, else in threads (see
        :mod:`torchfill.windows`). The first window runs alone and the fills blend in
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
    """

    method: str | None = None
    params: dict | None = None
    training: Any = None
    mask: Any = None
    max_gap: int | None = None
    window: int | None = _Default(WINDOW)
    progress: bool | Callable[[dict], None] | None = False
    constraints: bool = True
    extrapolate: float | None = 0.25
    return_std: bool = False
    dtype: Any = None
    workers: int | None = None
    segments: Any = None
    reject: float | None = None

    @classmethod
    def make(cls, method: str | None = None, **keywords: Any) -> "FillOptions":
        """Options from ``fill()``'s keywords, checked; keywords that are no option are the
        method's hyperparameters given the deprecated way (a DeprecationWarning)."""
        names = {f.name for f in fields(cls)}
        legacy = {k: v for k, v in keywords.items() if k not in names}
        given = {k: v for k, v in keywords.items() if k in names}
        window = "window" in given and not isinstance(given["window"], _Default)
        return cls(method=method, **given).checked(legacy, window_given=window)

    def checked(self, legacy: dict | None = None, window_given: bool = False) -> "FillOptions":
        """These options with the method's name resolved (default: the best registered) and
        every option checked; errors say what was expected and what was found. ``legacy``:
        hyperparameters given as ``fill()`` keywords; ``window_given``: ``window`` was one of
        ``fill()``'s keywords (an error for a method with a ``window`` of its own, unless
        ``params`` names that one)."""
        from .solvers import available

        method = default_method() if self.method is None else self.method
        if not isinstance(method, str) or not method.strip():
            raise ValueError(f"method expected one of {', '.join(available())}, found {method!r}")
        if method not in available():                   # case and "-" forgiven, as on the CLI
            method = resolve(method, available())
        params, training = _solver_params(method, self.params, self.training, legacy or {},
                                          window_given)
        _check_ranges(self)
        return replace(self, method=method, params=params, training=training)

    def keywords(self) -> dict[str, Any]:
        """The options as ``fill()`` keywords (``method`` aside)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "method"}

    def replace(self, **changes: Any) -> "FillOptions":
        return replace(self, **changes)


#: Preferred default, best first; the first registered one is used when ``method`` is not given.
#: ``auto``: per gap, the candidate methods that fill gaps of that kind best on the recording's
#: own observed data, with its error estimate (numbers in docs/real-gaps.md).
DEFAULT_METHODS = ("auto", "tucker_tnn", "tucker", "pchip")


def default_method() -> str:
    from .solvers import available

    return next(m for m in DEFAULT_METHODS if m in available())


def work_dtype(dtype, solver):
    """The torch dtype a method computes in: ``dtype`` (a torch dtype or its name), else the
    solver's ``fill_dtype`` (None: the data's own)."""
    import torch

    if dtype is None:
        return solver.fill_dtype
    found = getattr(torch, dtype, None) if isinstance(dtype, str) else dtype
    if found not in (torch.float32, torch.float64):
        raise ValueError(f"dtype expected 'float32' or 'float64', found {dtype!r}")
    return found


def _check_ranges(o: FillOptions) -> None:
    if o.max_gap is not None and o.max_gap < 0:
        raise ValueError(f"max_gap expected >= 0, found {o.max_gap}")
    w = o.window
    if w is not None and (isinstance(w, bool) or not isinstance(w, int) or w < 2):
        raise ValueError(f"window expected an int >= 2 or None, found {w!r}")
    n = o.workers
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"workers expected an int >= 1 or None, found {n!r}")
    if not (o.progress is None or isinstance(o.progress, bool) or callable(o.progress)):
        raise ValueError(f"progress expected True, False or a callable, found {o.progress!r}")


def _solver_params(method: str, params: dict | None, training, legacy: dict,
                   window_given: bool) -> tuple[dict, object]:
    """The method's hyperparameters from ``params`` (and, deprecated, ``fill()``'s extra keyword
    arguments), checked against ``fill()``'s own arguments; and the training data."""
    from .solvers import available, get_solver

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
                          DeprecationWarning, stacklevel=5)
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


#: The options' part of :class:`FillOptions`' docstring: ``fill()``'s documentation of them.
OPTIONS_DOC = FillOptions.__doc__.split("``DEFAULT_METHODS``).\n", 1)[1]
