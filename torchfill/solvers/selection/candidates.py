"""The default's candidate methods and their fits: which candidates run on a recording, each fitted
with some samples hidden (through the post-step ``fill()`` passes), side by side on threads.
Why each candidate and parameter: experiments/results/auto.md."""
from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import Future

import torch

from ... import ops
from ...runtime.memory import trim_heap
from ...runtime.threads import Lanes, after, thread_map
from ..base import available, get_solver
from .kinds import interior_share

Tensor = torch.Tensor

#: Candidates tried by default, in this order; names not registered (yet) are skipped: the
#: temporal interpolants for short gaps, the spatial models of Tits et al. 2018 (``li``,
#: ``lgrnn``, ``glr`` and their average ``pma``) and Gløersen PCA, which place a marker from the
#: markers seen in the same frame, ``rigid`` (segment-mates) and ``tucker_tnn`` for long interior
#: gaps and dense occlusion. Pass ``candidates=`` to try others (``svt``, ``cp``, ``pca_train``).
DEFAULT_CANDIDATES = ("pchip", "spline", "rigid", "li", "lgrnn", "glr", "pma", "pca_gloersen",
                      "tucker_tnn")
#: Default candidates that only run when interior gaps longer than ``LENGTH_EDGES[0]`` frames
#: hold at least ``INTERIOR_SHARE`` of the missing samples: a low-rank model in time extrapolates
#: poorly at trial ends, where most real gaps are, and it is most of the fits' time.
INTERIOR = ("tucker_tnn",)
INTERIOR_SHARE = 0.25
#: Candidates that fill only some samples (NaN elsewhere), with the parameters that make them so:
#: ``rigid`` where three segment-mates are seen and its own error estimate (measured on observed
#: frames) is within 5 % of the body's size. The samples such a candidate fills form gap kinds of
#: their own (see :func:`~.kinds.sample_kinds`), in which it competes with the others; elsewhere it
#: has no weight.
PARTIAL = {"rigid": {"fallback": False, "max_error": 0.05}}
#: With training recordings (fit data ``training``: the subject's other trials), the candidates in
#: ``TWINS`` learn from their frames too (:mod:`torchfill.solvers.session`), under the name
#: ``NAME+session``; the ones in ``ALONE`` also stay in as they were, so that the hold-out can
#: still choose the recording's own evidence where another trial misleads (a different motion).
#: A twin's fill of a gap touching one trial end is shifted as a whole onto the trajectory
#: continued from the gap's observed edge (:func:`end_shift`).
SESSION = "+session"
TWINS = ("li", "glr", "pma", "pca_gloersen")
ALONE = ("lgrnn", "pca_gloersen")
#: Relative time of a candidate's fit (others: 1), so that the longest start first when they run
#: side by side (:func:`torchfill.runtime.threads.thread_map`'s ``cost``); a ``+session`` twin as its method.
COST = {"tucker_tnn": 8.0, "rigid": 4.0, "pma": 4.0, "pchip": 0.3, "spline": 0.3,
        "pca_gloersen": 0.3}
#: ``COST`` of a refit where it differs: ``tucker_tnn``'s starts from its hold-out fit.
REFIT_COST = {"tucker_tnn": 1.0}
#: Candidates whose trial-end fills swing with the samples they see: there the final fill is the
#: mean of their hold-out fit and refit (experiments/results/auto.md).
END_AVERAGE = ("li", "lgrnn", "pma")
#: Errors that drop a candidate for this recording instead of failing the fill.
FAILURES = (ValueError, RuntimeError, torch.linalg.LinAlgError)


def cost(name: str, stage: str = "fit") -> float:
    """A candidate's relative time in a round of ``stage`` (``COST``, ``REFIT_COST``; a
    ``+session`` twin as its method)."""
    table = {**COST, **REFIT_COST} if stage == "refit" else COST
    return table.get(name.removesuffix(SESSION), 1.0)


def default_names(Omega: Tensor | None, training: bool) -> list[str]:
    """The default candidates for a recording with observed entries ``Omega`` (None: not known
    yet), as their ``+session`` twins with ``training``."""
    names = [name for name in DEFAULT_CANDIDATES if name in available()]
    if Omega is not None and interior_share(Omega) < INTERIOR_SHARE:
        names = [name for name in names if name not in INTERIOR]
    if training:
        names = [twin for name in names for twin in session_twins(name)]
    return names


def session_twins(name: str) -> list[str]:
    """With training data: a default candidate in ``TWINS`` as ``NAME+session``, and as
    itself too when in ``ALONE``; any other as itself."""
    solver = get_solver(name)
    if name not in TWINS or not solver.spatial or "training" not in solver.fit_data:
        return [name]
    return [name, name + SESSION] if name in ALONE else [name + SESSION]


def end_shift(F: Tensor, missing: Tensor) -> Tensor:
    """``F`` (T, J, D) with each gap of ``missing`` (T, J) that touches one trial end shifted as a
    whole onto the observed trajectory continued one frame at its speed from the gap's other edge
    (a constant offset: a model trained on another trial places a marker off by where that trial
    had it)."""
    T = F.shape[0]
    F = F.clone()
    for j, a, b in ops.runs(missing):
        if (a == 0) == (b == T):
            continue
        e, e2, t = (a - 1, a - 2, a) if a > 0 else (b, b + 1, b - 1)
        v = F[e, j] - F[e2, j] if 0 <= e2 < T and not bool(missing[e2, j]) else 0.0
        F[a:b, j] += F[e, j] + v - F[t, j]
    return F


class Post:
    """The post-step ``fill()`` passes as ``post`` fit data for one mask ``missing`` (T, J) of the
    observed ``M`` (T, J, D), one candidate's fill at a time (in its lane, as its fit ends):
    what the candidates share (``post.prepare``, see
    :func:`torchfill.constraints.prepare_candidates`) is made once, by the first fill that needs
    it. A ``post`` without ``prepare`` takes each fill alone; without a post-step, fills pass
    unchanged. ``donor``: the (T, J) samples rigid donors fill, once a fill went through."""

    def __init__(self, post: Callable | None, M: Tensor, missing: Tensor) -> None:
        self.post, self.M, self.missing = post, M, missing
        self.donor = torch.zeros_like(missing)
        self._one: Callable | None = None
        self._lock = threading.Lock()

    def __call__(self, F: Tensor) -> Tensor:
        if self.post is None:
            return F
        with self._lock:
            if self._one is None:
                self._one, donor = self._prepare()
                self.donor = donor if donor is not None else self.donor
        with warnings.catch_warnings():     # the candidates' post-step speaks to no one: the
            warnings.simplefilter("ignore")  # final fill's own post-step warns the user once
            return self._one(F)

    def _prepare(self) -> tuple[Callable, Tensor | None]:
        prepare = getattr(self.post, "prepare", None)
        if prepare is not None:
            return prepare(self.M, self.missing)

        def alone(F: Tensor) -> Tensor:
            G, self.donor = self.post(F[None], self.missing)
            return G[0]
        return alone, None


class Fits:
    """The candidates' fits of one recording ``M`` (the solver's normalized data, (T, J*D) or
    (T, J, D)) with ``mu`` / ``sigma`` its normalization, the solver's ``fit_data``, ``seed``,
    per-candidate ``params``, the user's ``explicit`` candidates (None: the default ones),
    ``carried`` (each candidate's :meth:`Solver.carry` from its first fit, filled as they run)
    and ``report`` (progress records)."""

    def __init__(self, M: Tensor, mu: Tensor, sigma: Tensor, fit_data: dict, seed,
                 params: dict | None, explicit, carried: dict,
                 report: Callable[[dict], None]) -> None:
        self.M, self.mu, self.sigma, self.fit_data = M, mu, sigma, fit_data
        self.seed, self.params, self.explicit = seed, params or {}, explicit
        self.carried, self.report = carried, report
        self.warm: dict[str, tuple] = {}        # each candidate's first fit's warm_start()
        self.lanes: Lanes | None = None         # worker threads kept open (:meth:`open_lanes`)
        self.first: dict[str, Future] = {}      # first fits left running (``behind``)
        self._posts: dict[bytes, Post] = {}     # the rounds' post-steps, by mask
        self._post_lock = threading.Lock()

    def open_lanes(self) -> Lanes:
        """Worker threads for the fits of this recording (one on a GPU), kept open across the
        rounds so that a long fit runs on beside the next draws: ``with fits.open_lanes():``."""
        self.lanes = Lanes(None if self.M.device.type == "cpu" else 1)
        return self.lanes

    def in_lanes(self, size: int) -> bool:
        """Whether the fits of a round of ``size`` run in the open lanes: each on the intra-op
        threads :func:`thread_map` would give it (there: one, for a round of at least as many
        fits as lanes), so that one of them can also run on in the background (``behind``)."""
        return self.lanes is not None and self.lanes.parallel and size >= self.lanes.workers

    def fit_one(self, name: str, fit_missing: Tensor, case: tuple | None = None,
                stage: str = "fit") -> Tensor:
        """Candidate ``name`` fitted with ``fit_missing`` (T, J) hidden; its fill (T, J, 3).
        ``case``: another recording to fit instead, ``(M, training)`` in the fit's units (the
        cross-trial hold-out, see :func:`~.cross.cross_holdout`); nothing is carried from it.
        ``stage`` ``"refit"``: started from this candidate's first fit (its ``warm_start()``)."""
        T, J = fit_missing.shape
        M = self.M if case is None else case[0]
        X = torch.where(fit_missing[..., None], float("nan"), M.reshape(T, J, -1))
        method = name.removesuffix(SESSION)
        params = {"seed": self.seed, **PARTIAL.get(method, {}), **self.params.get(method, {}),
                  **self.carried.get(name, {})}
        warm = self.warm.get(name, ({}, {})) if stage == "refit" else ({}, {})
        params.update(warm[0])              # a refit starts from the first fit (warm_start())
        solver = get_solver(method, **params)
        takes = [k for k in solver.fit_data              # a spatial default candidate learns
                 if k != "training" or name.endswith(SESSION)     # from training as +session
                 or not solver.spatial or name in (self.explicit or ())]
        data = {k: [(t - self.mu) / self.sigma for t in v] if k == "training" else v
                for k, v in self.fit_data.items() if k in takes}   # training in the fit's units
        if case is not None and "training" in data:
            data["training"] = case[1]
        data.update(warm[1])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = solver.fit_transform(X, fit_missing, **data)
        if case is None and name not in self.carried:    # the later fits reuse the first's
            self.carried[name] = solver.carry()
            self.warm[name] = solver.warm_start()
        if name.endswith(SESSION):
            out = end_shift(out, fit_missing)
        done = torch.isfinite(out).all(dim=-1)
        if name in PARTIAL and bool(done[fit_missing].any()):
            return out.to(self.M.dtype)                     # NaN where it does not fill
        if not bool(done.all()):
            raise ValueError("non-finite fill")
        return out.to(self.M.dtype)

    def attempt(self, name: str, fit_missing: Tensor, case: tuple | None = None,
                stage: str = "fit") -> Tensor | Exception:
        """:meth:`fit_one`, or the error that drops the candidate."""
        try:
            return self.fit_one(name, fit_missing, case, stage)
        except FAILURES as err:
            return err
        finally:                        # the fit's solver is gone: its freed memory goes back
            trim_heap(self.M.element_size() * self.M.numel())

    def fit_all(self, names: list[str], fit_missing: Tensor, stage: str = "fit",
                case: tuple | None = None, behind: tuple = (),
                then: Callable[[str, Tensor], Tensor] | None = None) -> Iterator:
        """:meth:`attempt` for each name, in order; on CPU in threads (``runtime.threads``: in
        the open lanes, else for this call alone), the costliest first. Each finished fit is
        reported: ``{stage}=k``, ``{stage}s=n`` (``fit``/``fits`` on the hold-out,
        ``refit``/``refits``; the step's own record counts the ``candidates`` that ran). In the
        lanes (:meth:`in_lanes`), the names in ``behind`` are not waited for: their place holds
        the :class:`~concurrent.futures.Future` of their fit, which runs on in the background; a
        later fit of a candidate whose first fit runs so starts when that ends (it reads what the
        first carries, :meth:`Solver.carry`). ``then(name, fill)``: what a fit's fill becomes
        in its lane as it ends (the post-step: :meth:`post`)."""
        lock, done = threading.Lock(), [0]

        def attempt(name: str):
            out = self.attempt(name, fit_missing, case, stage)
            if then is not None and not isinstance(out, Exception):
                out = then(name, out)
            with lock:
                done[0] += 1
                self.report({stage: float(done[0]), f"{stage}s": float(len(names))})
            return out
        if not self.in_lanes(len(names)):
            workers = None if self.M.device.type == "cpu" else 1
            return thread_map(attempt, names, workers, cost=lambda name: cost(name, stage))
        futures = {i: self._submit(attempt, names[i])
                   for i in sorted(range(len(names)), key=lambda i: -cost(names[i], stage))}
        if stage == "fit" and case is None:
            self.first.update({names[i]: f for i, f in futures.items() if names[i] in behind})
        return (futures.pop(i) if names[i] in behind else futures.pop(i).result()
                for i in range(len(names)))

    def _submit(self, attempt: Callable, name: str) -> Future:
        """``attempt(name)`` in the next free lane, or, while the candidate's first fit runs, in
        its lane as soon as that ends."""
        first = self.first.get(name)
        if first is None or first.done():
            return self.lanes.submit(attempt, name)
        return after(first, self.lanes, attempt, name)

    def post(self, missing: Tensor) -> Post:
        """The post-step of a fill with ``missing`` (T, J) hidden (:class:`Post`), kept for the
        masks of this recording's rounds (their shared part is made once)."""
        key = missing.cpu().numpy().tobytes()
        with self._post_lock:
            if key not in self._posts:
                Xt = self.M.reshape(*missing.shape, -1)
                self._posts[key] = Post(self.fit_data.get("post"), Xt, missing)
            return self._posts[key]

    def constrained(self, missing: Tensor) -> Callable[[str, Tensor], Tensor]:
        """``then`` for :meth:`fit_all`: a fit's fill with ``missing`` hidden through the
        post-step."""
        post = self.post(missing)
        return lambda name, out: post(out)

    def run(self, names: list[str], fit_missing: Tensor, dropped: dict[str, str],
            behind: tuple = ()) -> tuple[list[str], list[Tensor | Future]]:
        """Each candidate of ``names`` fitted once with ``fit_missing`` hidden, through the
        post-step (:meth:`constrained`): the names of those that did not fail (the others'
        errors go to ``dropped``) and their fills (T, J, 3), the
        :class:`~concurrent.futures.Future` of those in ``behind`` still running (see
        :meth:`fit_all`)."""
        kept, fills = [], []
        then = self.constrained(fit_missing)
        for name, out in zip(names, self.fit_all(names, fit_missing, behind=behind, then=then)):
            if isinstance(out, Exception):
                dropped[name] = str(out)
                continue
            kept.append(name)
            fills.append(out)
        return kept, fills

    def refit(self, names: list[str], fills: Tensor, w: Tensor, gaps: Tensor,
              end: Tensor) -> tuple[Tensor, Tensor]:
        """Fills of the real ``gaps`` from the candidates that carry weight there (``w`` (C, T,
        J)), refitted on all observed samples (the hold-out fit stays where the refit fails),
        constrained like the hold-out fills (the held-out samples as observed); and the (T, J)
        samples that rigid donors fill. On the samples of the trial-end kinds (``end``, (T, J))
        a candidate of ``END_AVERAGE`` takes the mean of its refit and its hold-out fill
        ``fills``."""
        fills = fills.clone()
        done = [c for c in range(len(names)) if bool((w[c][gaps] > 0).any())]
        Xt, post = self.M.reshape(fills.shape[1:]), self.post(gaps)

        def then(name: str, out: Tensor) -> Tensor:
            if name in END_AVERAGE:
                out = torch.where(end[..., None], 0.5 * (out + fills[names.index(name)]), out)
            return post(torch.where(gaps[..., None], out, Xt))
        chosen = [names[c] for c in done]
        for c, out in zip(done, self.fit_all(chosen, gaps, "refit", then=then)):
            if not isinstance(out, Exception):
                fills[c] = torch.where(gaps[..., None], out, fills[c])
        trim_heap(self.M.element_size() * self.M.numel())
        return fills, post.donor
