"""The solver contract (see DESIGN.md): :class:`Solver`, declared hyperparameters, the registry.

Every filler is a ``torch.nn.Module`` with keyword-only hyperparameters, ``fit(X, mask)``,
``step()`` (one update of the paper's algorithm), ``forward()`` (the current reconstruction) and
``history_``. The same loop, stopping rule and history record serve every solver. Two contracts:
an iterative :class:`Solver` repeats ``step()`` until its stopping rule or ``max_iter``; a
:class:`OneShotSolver` computes its fill in one ``step()`` and declares neither ``max_iter`` nor
``tol``.
"""
from __future__ import annotations

import functools
import inspect
import math
import operator
import re
import textwrap
import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from .. import ops

Tensor = torch.Tensor


@dataclass(frozen=True)
class Param:
    """A declared hyperparameter: default, accepted types and bounds (inclusive unless open)."""

    default: Any
    types: type | tuple[type, ...] = float
    low: float | None = None
    high: float | None = None
    choices: tuple | None = None
    allow_none: bool = False
    low_open: bool = False
    doc: str = ""

    def check(self, owner: str, name: str, value: Any) -> Any:
        if value is None and self.allow_none:
            return None
        types = self.types if isinstance(self.types, tuple) else (self.types,)
        if float in types and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if isinstance(value, bool) and bool not in types or not isinstance(value, types):
            raise ValueError(f"{owner}: {name} expected {self._expected()}, "
                             f"found {value!r} ({type(value).__name__})")
        ok = self.choices is None or value in self.choices
        if self.low is not None:
            ok = ok and (value > self.low if self.low_open else value >= self.low)
        if self.high is not None:
            ok = ok and value <= self.high
        if isinstance(value, float) and not math.isfinite(value) and self.high is not None:
            ok = False
        if not ok:
            raise ValueError(f"{owner}: {name} expected {self._expected()}, found {value!r}")
        return value

    def _expected(self) -> str:
        types = self.types if isinstance(self.types, tuple) else (self.types,)
        text = " or ".join(t.__name__ for t in types)
        if self.choices is not None:
            text += f" in {self.choices}"
        if self.low is not None:
            text += f" {'>' if self.low_open else '>='} {self.low}"
        if self.high is not None:
            text += f" <= {self.high}"
        return text + (" or None" if self.allow_none else "")


def refuse_grad(X, owner: str) -> None:
    """A one-line ``ValueError`` for data that require grad: a fill is not differentiable with
    respect to its data (the solvers' updates run without autograd), so no gradient is kept."""
    if isinstance(X, Tensor) and X.requires_grad:
        raise ValueError(f"{owner}: the data require grad, but a fill is not differentiable with "
                         "respect to its input; pass X.detach()")


class NotConvergedWarning(UserWarning):
    """A fit stopped at ``max_iter`` before its stopping rule was met (the result is the last, or
    the best held-out, iterate; raise ``max_iter`` or loosen ``tol``)."""


def _type_names(spec: Param) -> str:
    types = spec.types if isinstance(spec.types, tuple) else (spec.types,)
    text = " or ".join(t.__name__ for t in types)
    if spec.choices is not None:
        text = "{" + ", ".join(repr(c) for c in spec.choices) + "}"
    return text + (" or None" if spec.allow_none else "")


def _annotation(spec: Param) -> Any:
    types = spec.types if isinstance(spec.types, tuple) else (spec.types,)
    ann = functools.reduce(operator.or_, types)
    return ann | None if spec.allow_none else ann


def parameters_section(params: dict[str, Param]) -> str:
    """The numpydoc ``Parameters`` section of declared hyperparameters."""
    lines = ["Parameters", "----------"]
    for key, spec in params.items():
        lines.append(f"{key} : {_type_names(spec)}, default {spec.default!r}")
        lines.extend(textwrap.wrap(spec.doc or "(undocumented)", 92, initial_indent="    ",
                                   subsequent_indent="    "))
    return "\n".join(lines)


_SECTION = re.compile(r"^(\w[\w ]*)\n-{3,}$", re.M)


def _with_parameters(doc: str, section: str) -> str:
    """``doc`` (cleaned) with its Parameters section replaced by ``section``, placed before the
    first later numpydoc section (References, Notes, ...) or at the end."""
    doc = inspect.cleandoc(doc)
    heads = [(m.start(), m.group(1)) for m in _SECTION.finditer(doc)]
    for i, (start, name) in enumerate(heads):
        if name == "Parameters":
            end = heads[i + 1][0] if i + 1 < len(heads) else len(doc)
            doc = doc[:start].rstrip() + "\n\n" + doc[end:]
            return _with_parameters(doc, section)
    after = [start for start, name in heads if name not in ("Attributes",)]
    at = after[0] if after else len(doc)
    return (doc[:at].rstrip() + "\n\n" + section + "\n\n" + doc[at:]).rstrip() + "\n"


class _ClassSignature:
    """``Solver.__signature__`` on the class only: the keyword-only hyperparameters, so that
    ``inspect.signature(cls)``, ``help()`` and IDEs show them (instances keep ``forward()``'s)."""

    def __get__(self, obj: Any, cls: type) -> inspect.Signature:
        if obj is not None:
            raise AttributeError("__signature__")
        return inspect.Signature([
            inspect.Parameter(key, inspect.Parameter.KEYWORD_ONLY, default=spec.default,
                              annotation=_annotation(spec))
            for key, spec in cls.declared_params().items()])


def _deprecated(owner: str, old: str, new: str) -> None:
    warnings.warn(f"{owner}: {old!r} is deprecated and will be removed in the next release; "
                  f"use {new!r}", DeprecationWarning, stacklevel=4)


_PLAIN = (int, float, bool, str, type(None))


def _is_plain(value: Any) -> bool:
    """Whether ``value`` is a plain value ``torch.load(weights_only=True)`` reads back."""
    if isinstance(value, _PLAIN):
        return True
    if isinstance(value, (list, tuple)):
        return all(_is_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, (str, int)) and _is_plain(v) for k, v in value.items())
    return False


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):                  # torch.Size and named tuples as plain tuples
        return tuple(_plain(v) for v in value)
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype a solver computes in for data of ``dtype``: float32 and float64 as they are,
    float16 and bfloat16 in float32 (their 3-4 significant digits cannot carry an iterative fit),
    anything else (integers, bool) in float64."""
    if dtype in (torch.float32, torch.float64):
        return dtype
    if dtype in (torch.float16, torch.bfloat16):
        return torch.float32
    return torch.float64


def _as_dtype(value: Any, dtype: torch.dtype) -> Any:
    """Fit data (``training``: a tensor or a list of them) in the compute dtype of a half fit."""
    if isinstance(value, Tensor) and value.dtype in (torch.float16, torch.bfloat16):
        return value.to(dtype)
    if isinstance(value, (list, tuple)):
        return type(value)(_as_dtype(v, dtype) for v in value)
    return value


_REGISTRY: dict[str, type["Solver"]] = {}


def register(cls: type["Solver"]) -> type["Solver"]:
    """Class decorator: add a solver to the registry under ``cls.name``."""
    if not cls.name or cls.name in _REGISTRY:
        raise ValueError(f"solver name {cls.name!r} is empty or already registered")
    _REGISTRY[cls.name] = cls
    return cls


def available() -> list[str]:
    """Registered method names, in registration order."""
    return list(_REGISTRY)


def get_solver(name: str, **params: Any) -> "Solver":
    """Instantiate the registered solver ``name`` with hyperparameters ``params``."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown method {name!r}; expected one of: {', '.join(_REGISTRY)}")
    return _REGISTRY[name](**params)


class Solver(nn.Module):
    """Base class of every gap filler.

    Subclasses set ``name``, declare their hyperparameters in ``params`` (merged along the MRO) and
    implement :meth:`_initialize` (state from the normalized data), :meth:`step` (one update,
    returning a dict of observed-data diagnostics for ``history_``) and :meth:`_estimate` (the
    current full estimate, normalized).

    Data handling shared by all: ``fit`` centres each coordinate axis (last mode) on its observed
    mean and divides by one scalar, the observed standard deviation, so every default is
    translation- and unit-invariant. ``M_`` holds the normalized data with zeros where missing,
    ``Omega_`` the observed set (bool, full shape). Missing entries are zeroed before anything else,
    so a solver never sees values the caller passed at unobserved positions.

    As a module: every fitted tensor (an attribute ending in ``_``) is a buffer, so ``.to(device
    or dtype)`` moves the whole fit and ``forward()`` then runs in the new dtype; fitted
    factorizations are submodules. ``state_dict()`` holds the buffers and, as extra state, the
    fitted plain values (``n_iter_``, ``history_``, chosen ranks); it loads into a fresh solver of
    the same class and hyperparameters (``load_state_dict``), after which ``transform`` gives the
    same fill. Loading needs no pickle: ``torch.load(..., weights_only=True)`` reads it.

    Dtypes: float16 and bfloat16 data are computed in float32 and the fill returned in the caller's
    dtype; integer data in float64.

    Batches: ``fit`` takes ``(B, T, J, D)`` with a mask ``(B, T, J)`` (or ``(B, T, J, D)``) and
    fits each sequence in turn (one fitted solver per sequence in ``members_``; no method solves
    a batch jointly); ``transform`` and ``forward`` return the batch.

    Threads: ``fit``, ``transform`` and ``fit_transform`` of one solver hold its lock, so calls from
    two threads run one after the other and ``fit_transform`` returns its own fit; a ``fit`` in
    one thread and a later ``transform`` in another see whichever fit ran last. Use one solver
    per thread (solvers are cheap to create) to fill in parallel.
    """

    name: ClassVar[str] = ""
    iterative: ClassVar[bool] = True
    params: ClassVar[dict[str, Param]] = {
        "max_iter": Param(500, int, low=1, doc="iteration cap"),
        "tol": Param(1e-5, float, low=0.0, doc="stop when the relative change of the iterate is below"),
        "seed": Param(0, int, doc="seed of the solver's own random generator"),
        "verbose": Param(False, bool, doc="print one line per iteration"),
    }

    #: names of the data ``fit`` takes besides ``X`` and ``mask`` (e.g. ``("training",)``)
    fit_data: ClassVar[tuple[str, ...]] = ()
    #: places a missing marker from the markers seen in the same frame (not only along time):
    #: fill()'s extrapolation limit then cuts only trial-end frames too empty for that
    spatial: ClassVar[bool] = False
    #: fill()'s finish keeps this method's short interior gaps on the interpolation across them
    #: where its fill departs from it, and bounds its error estimate by what the fill can be off
    #: (torchfill.qc.finish; docs/real-gaps.md, "Short gaps")
    finish_short_gaps: ClassVar[bool] = False
    #: the dtype ``fill()`` runs this solver in unless told otherwise (None: the input's, float64);
    #: the solver itself always follows the dtype it is given
    fill_dtype: ClassVar[torch.dtype | None] = None
    #: old hyperparameter spellings, accepted for one release with a DeprecationWarning: old -> new
    renamed: ClassVar[dict[str, str]] = {}
    #: old names of fitted attributes (read with a DeprecationWarning): old -> new
    renamed_attributes: ClassVar[dict[str, str]] = {}

    __signature__ = _ClassSignature()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.__doc__ = _with_parameters(cls.__doc__ or cls.__name__,
                                       parameters_section(cls.declared_params()))

    def __init__(self, **kwargs: Any) -> None:
        super().__init__()
        kwargs = self._upgrade(dict(kwargs))
        declared = self.declared_params()
        unknown = set(kwargs) - set(declared)
        if unknown:
            raise ValueError(f"{self.name}: unknown hyperparameter(s) {sorted(unknown)}; "
                             f"expected some of {sorted(declared)}")
        for key, spec in declared.items():
            setattr(self, key, spec.check(self.name, key, kwargs.get(key, spec.default)))
        self.history_: list[dict[str, float]] = []
        self.n_iter_ = 0
        self.converged_ = False
        self._lock = threading.RLock()

    # -- a module whose fitted state is buffers ------------------------------------------------
    def __setattr__(self, name: str, value: Any) -> None:
        """A tensor assigned to a fitted attribute (name ending in ``_``) becomes a buffer."""
        if (isinstance(value, Tensor) and not isinstance(value, nn.Parameter)
                and name.endswith("_") and not name.startswith("_")
                and "_buffers" in self.__dict__ and name not in self._buffers
                and name not in self._parameters):
            self.__dict__.pop(name, None)
            self.register_buffer(name, value)
            return
        super().__setattr__(name, value)

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__() if hasattr(super(), "__getstate__") else self.__dict__.copy()
        state = dict(state)
        state.pop("_lock", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        super().__setstate__(state)
        self._lock = threading.RLock()

    def _reset_fit(self) -> None:
        """Drop the fitted buffers and submodules of an earlier fit."""
        for store in (self._buffers, self._modules):
            for key in [k for k in store if k.endswith("_")]:
                del store[key]

    def get_extra_state(self) -> dict[str, Any]:
        """The fitted plain values (ints, floats, strings, bools and containers of them) and the
        classes of fitted submodules, for ``state_dict``."""
        values = {k: _plain(v) for k, v in vars(self).items()
                  if k.endswith("_") and not k.startswith("_") and _is_plain(v)}
        modules = {k: type(m).__name__ for k, m in self._modules.items() if k.endswith("_")}
        return {"values": values, "modules": modules}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        for key, value in state.get("values", {}).items():
            setattr(self, key, value)

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing_keys,
                              unexpected_keys, error_msgs) -> None:
        """A fresh solver takes a fitted one's state: its buffers and submodules are made from
        the keys (shape, dtype and device of the saved tensors) before they are copied in."""
        extra = state_dict.get(prefix + "_extra_state", {})
        for cls_key, cls_name in (extra.get("modules", {}) if isinstance(extra, dict) else {}).items():
            if cls_key not in self._modules:
                made = self._fresh_module(cls_name, prefix + cls_key + ".", state_dict)
                if made is not None:
                    self._modules[cls_key] = made
        for key, value in state_dict.items():
            if not key.startswith(prefix):
                continue
            name = key[len(prefix):]
            if ("." not in name and name.endswith("_") and not name.startswith("_")
                    and name not in self._buffers and name not in self._parameters
                    and isinstance(value, Tensor)):
                self.__dict__.pop(name, None)
                self.register_buffer(name, torch.empty_like(value))
        super()._load_from_state_dict(state_dict, prefix, local_metadata, strict, missing_keys,
                                      unexpected_keys, error_msgs)

    def _fresh_module(self, cls_name: str, prefix: str, state_dict: dict) -> nn.Module | None:
        """An empty fitted submodule of class ``cls_name`` to load ``prefix...`` keys into."""
        from .factorized import _Factorized
        if cls_name == "ModuleList":                       # batch members: same class, same params
            idx = {int(k[len(prefix):].split(".")[0]) for k in state_dict if k.startswith(prefix)}
            return nn.ModuleList(type(self)(**self.get_params()) for _ in range(max(idx, default=-1) + 1))
        for klass in _Factorized.__subclasses__():
            if klass.__name__ == cls_name:
                return klass.empty()
        return None

    @classmethod
    def declared_params(cls) -> dict[str, Param]:
        """The hyperparameters, merged along the MRO (a ``None`` entry takes an inherited one
        back: :class:`OneShotSolver`'s ``max_iter`` and ``tol``)."""
        merged: dict[str, Param] = {}
        for klass in reversed(cls.__mro__):
            merged.update(getattr(klass, "params", {}) if issubclass(klass, Solver) else {})
        return {key: spec for key, spec in merged.items() if spec is not None}

    @classmethod
    def _merged(cls, attr: str) -> dict[str, str]:
        merged: dict[str, str] = {}
        for klass in reversed(cls.__mro__):
            merged.update(vars(klass).get(attr, {}) if issubclass(klass, Solver) else {})
        return merged

    @classmethod
    def _upgrade(cls, kwargs: dict[str, Any]) -> dict[str, Any]:
        """Old spellings of hyperparameters (``renamed``) mapped to the new ones, with a
        DeprecationWarning. Subclasses that changed a value's type translate it here too."""
        for old, new in cls._merged("renamed").items():
            if old in kwargs:
                if new in kwargs:
                    raise ValueError(f"{cls.name}: {old} and {new} given; {old} is the old name of {new}")
                _deprecated(cls.name, old, new)
                kwargs[new] = kwargs.pop(old)
        return kwargs

    def __getattr__(self, name: str) -> Any:
        try:
            return super().__getattr__(name)
        except AttributeError:
            cls = type(self)
            new = {**cls._merged("renamed"), **cls._merged("renamed_attributes")}.get(name)
            if new is None:
                raise
            _deprecated(cls.name, name, new)
            return getattr(self, new)

    def get_params(self) -> dict[str, Any]:
        return {key: getattr(self, key) for key in self.declared_params()}

    # -- data in -------------------------------------------------------------------------------
    def initialize(self, X: Tensor, mask: Tensor | None = None, **data: Any) -> "Solver":
        """Take the data and set up the state without iterating (the Lightning runners call this).

        ``data``: what the solver takes besides ``X`` and ``mask`` (its ``fit_data``, e.g. the PCA
        methods' ``training``), kept in ``fit_data_``.
        """
        unknown = set(data) - set(self.fit_data)
        if unknown:
            raise ValueError(f"{self.name}: fit() got unexpected data {sorted(unknown)}; expected "
                             f"X, mask{''.join(', ' + k for k in self.fit_data)}")
        self._reset_fit()
        X = torch.as_tensor(X)
        if X.ndim < 2:
            raise ValueError(f"{self.name}: expected a tensor with time as its first mode, found shape {tuple(X.shape)}")
        refuse_grad(X, self.name)
        dtype = compute_dtype(X.dtype)
        X = X.to(dtype)
        self.fit_data_ = {k: _as_dtype(v, dtype) for k, v in data.items() if v is not None}
        Omega = torch.isfinite(X)
        if mask is not None:
            mask = torch.as_tensor(mask, dtype=torch.bool, device=X.device)
            if mask.shape != X.shape:
                if mask.shape != X.shape[:mask.ndim]:
                    raise ValueError(f"{self.name}: mask shape {tuple(mask.shape)} does not match data {tuple(X.shape)}")
                mask = mask.reshape(mask.shape + (1,) * (X.ndim - mask.ndim)).expand_as(X)
            Omega = Omega & ~mask
        if not bool(Omega.any()):
            raise ValueError(f"{self.name}: no observed entries to fit")
        zero = torch.zeros((), dtype=dtype, device=X.device)
        Xo = torch.where(Omega, X, zero)
        axes = tuple(range(X.ndim - 1))
        count = Omega.sum(dim=axes).clamp(min=1)
        self.mu_ = Xo.sum(dim=axes) / count                       # per coordinate (last mode)
        centred = torch.where(Omega, X - self.mu_, zero)
        sigma = torch.sqrt((centred ** 2).sum() / Omega.sum().clamp(min=1))
        self.sigma_ = torch.where(sigma > 0, sigma, torch.ones_like(sigma))
        self.M_ = centred / self.sigma_
        self.Omega_ = Omega
        self.fit_eps_ = float(torch.finfo(dtype).eps)        # transform() after .to(): see there
        self.generator_ = torch.Generator(device=X.device).manual_seed(self.seed)
        self.history_, self.n_iter_, self.converged_ = [], 0, False
        self._initialize()
        return self

    def require_3d(self, why: str) -> None:
        """Refuse data that are not 3-D markers ``(T, J, 3)`` (e.g. 2-D keypoints), saying why."""
        if self.M_.ndim != 3 or self.M_.shape[2] != 3:
            raise ValueError(f"{self.name}: expected 3-D markers (T, J, 3), found "
                             f"{tuple(self.M_.shape)} ({why})")

    def interp_start(self, observed: Tensor | None = None, *, relative: bool = False) -> Tensor:
        """The one interpolation start: the normalized data with the gaps of ``observed`` (default
        ``Omega_``; a fit mask leaves held-out samples out too) linearly interpolated along time,
        or, ``relative=True``, relative to the centroid of the observed markers
        (:func:`torchfill.ops.interp_relative`, which follows a travelling body)."""
        observed = self.Omega_ if observed is None else observed
        if relative:
            return ops.interp_relative(self.M_, observed)
        T = self.M_.shape[0]
        return ops.interp_linear(self.M_.reshape(T, -1), observed.reshape(T, -1)).reshape(self.M_.shape)

    # -- the loop ------------------------------------------------------------------------------
    def fit(self, X: Tensor, mask: Tensor | None = None, *,
            callback: Callable[[dict[str, float]], None] | None = None, **data: Any) -> "Solver":
        """Fit on ``X`` (NaN = missing, and/or ``mask`` True = missing); returns ``self``.

        ``callback``, if given, receives every iteration's history record (progress display).
        ``data``: the solver's other data (``fit_data``, e.g. ``training=`` for the PCA methods).
        """
        with self._lock:
            X = torch.as_tensor(X)
            if X.ndim == 4:
                return self._fit_batch(X, mask, callback, **data)
            return self._fit(X, mask, callback, **data)

    def _fit(self, X: Tensor, mask: Tensor | None, callback, **data: Any) -> "Solver":
        self.initialize(X, mask, **data)
        self.callback_ = callback
        try:
            while not self.converged_ and self.n_iter_ < self.max_iter:
                record = self.step_and_record()
                if callback is not None:
                    callback(record)
        finally:
            self.callback_ = None
        self.finalize()
        if not self.converged_:
            warnings.warn(f"{self.name}: stopped at max_iter={self.max_iter} before the stopping "
                          f"rule was met", NotConvergedWarning, stacklevel=3)
        return self

    def _fit_batch(self, X: Tensor, mask: Tensor | None, callback, **data: Any) -> "Solver":
        """``(B, T, J, D)``: one fit per sequence (its own mask), kept in ``members_``."""
        if mask is not None:
            mask = torch.as_tensor(mask, dtype=torch.bool, device=X.device)
            if mask.shape[0] != X.shape[0]:
                raise ValueError(f"{self.name}: a batch of {X.shape[0]} sequences needs a mask per "
                                 f"sequence, found mask shape {tuple(mask.shape)}")
        self._reset_fit()
        members = nn.ModuleList(type(self)(**self.get_params()) for _ in range(X.shape[0]))
        for b, member in enumerate(members):
            member._fit(X[b], None if mask is None else mask[b], callback, **data)
        self.members_ = members
        self.n_iter_ = sum(m.n_iter_ for m in members)
        self.converged_ = all(m.converged_ for m in members)
        self.history_ = [{"sequence": float(b), **h} for b, m in enumerate(members) for h in m.history_]
        return self

    def finalize(self) -> None:
        """End of a fit (after the last ``step``): solvers that keep a best iterate or helper state
        restore or drop it here. Whoever drives ``step()`` by hand (the Lightning runner) calls it."""

    def step_and_record(self) -> dict[str, float]:
        """One :meth:`step`, its diagnostics appended to ``history_``, the stopping rule applied."""
        info = self.step()
        self.n_iter_ += 1
        info = {"iter": self.n_iter_, **{k: float(v) for k, v in info.items()}}
        self.history_.append(info)
        self.converged_ = bool(self.should_stop(info))
        if self.verbose:
            print(f"[{self.name}] " + "  ".join(f"{k}={v:.4g}" for k, v in info.items()))
        return info

    def report(self, info: dict[str, float]) -> None:
        """Progress inside one long :meth:`step` (``auto``'s candidate fits) to the fit's
        ``callback``, as a record of the iteration under way (not kept in ``history_``)."""
        callback = getattr(self, "callback_", None)
        if callback is not None:
            callback({"iter": self.n_iter_ + 1, **info})

    def should_stop(self, info: dict[str, float]) -> bool:
        """Default rule: relative change of the iterate below ``tol`` (observed data only)."""
        if not self.iterative:
            return True
        return info.get("delta", math.inf) < self.tol

    def fit_transform(self, X: Tensor, mask: Tensor | None = None, **data: Any) -> Tensor:
        """Fit, then return ``X`` with its missing entries filled; observed entries are ``X``'s own."""
        with self._lock:
            X = torch.as_tensor(X)
            self.fit(X, mask, **data)
            return self.transform(X)

    def transform(self, X: Tensor) -> Tensor:
        """``X`` -- the data the solver was fitted on -- with the samples the fit did not observe
        (NaN or masked) filled; observed samples are ``X``'s own, bit for bit; the result has
        ``X``'s shape, dtype (float16 and bfloat16 included; integers become float64) and device.

        The solvers complete the tensor they were fitted on (transductive): other data -- another
        shape, or other values at the fitted observed samples -- raise a ValueError (fit on them,
        ``fit_transform``, to fill them)."""
        with self._lock:
            X = torch.as_tensor(X)
            if "members_" in self._modules:
                if X.ndim != 4 or X.shape[0] != len(self.members_):
                    raise ValueError(f"{self.name}: fitted on a batch of {len(self.members_)} "
                                     f"sequences; transform() got shape {tuple(X.shape)}")
                return torch.stack([m.transform(x) for m, x in zip(self.members_, X)])
            if "Omega_" not in self._buffers:
                raise RuntimeError(f"{self.name}: not fitted; call fit(X) first (or fit_transform)")
            if tuple(X.shape) != tuple(self.Omega_.shape):
                raise ValueError(f"{self.name}: transform() fills the data the solver was fitted on, "
                                 f"shape {tuple(self.Omega_.shape)}; found shape {tuple(X.shape)} "
                                 f"(fit_transform fills other data)")
            out_dtype = X.dtype if X.is_floating_point() else torch.float64
            Omega = self.Omega_
            Xw = X.to(device=Omega.device, dtype=self.M_.dtype)
            fitted = self.M_ * self.sigma_ + self.mu_
            # the fitted data are compared at the coarser of the fit's and the state's precision
            # (a fit moved by .to(dtype) keeps the rounding of the dtype it was made in)
            eps = max(torch.finfo(Xw.dtype).eps, getattr(self, "fit_eps_", 0.0))
            tol = 64 * eps * (Xw.abs() + self.mu_.abs() + self.sigma_)
            same = torch.where(Omega, (Xw - fitted).abs() <= tol, True)
            if not bool(same.all()):
                raise ValueError(f"{self.name}: transform() got other data than the solver was "
                                 f"fitted on ({int((~same).sum())} observed value(s) differ); "
                                 f"fit_transform fills other data")
            est = self.forward().to(device=X.device, dtype=out_dtype)
            return torch.where(Omega.to(X.device), X.to(out_dtype), est)

    def carry(self) -> dict[str, Any]:
        """Hyperparameters the next window of the same recording is filled with (what this fit
        chose on its observed samples and the next window need not search again); none here."""
        return {}

    def warm_start(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """Hyperparameters and fit data for a refit of the SAME recording with more samples
        seen, started from this fit (the default's refits after its hold-out fits); none here:
        the refit starts afresh."""
        return {}, {}

    def forward(self) -> Tensor:
        """The current full estimate, in the units of the input (a batch: ``(B, T, J, D)``)."""
        if "members_" in self._modules:
            return torch.stack([m.forward() for m in self.members_])
        return self._estimate() * self.sigma_ + self.mu_

    # -- to implement --------------------------------------------------------------------------
    def _initialize(self) -> None:
        raise NotImplementedError

    def step(self) -> dict[str, float]:
        raise NotImplementedError

    def _estimate(self) -> Tensor:
        raise NotImplementedError

    def extra_repr(self) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())


class OneShotSolver(Solver):
    """A solver whose fill is one computation (interpolation, a closed-form PCA fill, a rigid
    reconstruction, ``auto``'s choice): ``fit`` runs :meth:`step` once, so it declares neither
    ``max_iter`` nor ``tol``; ``max_iter`` reads 1 for the progress display and the runners."""

    iterative = False
    max_iter: ClassVar[int] = 1
    params = {"max_iter": None, "tol": None}
