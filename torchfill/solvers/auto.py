"""``auto``: per gap, the candidate methods that fill gaps of that kind best on THIS recording, and
an estimate of each filled sample's error.

How (observed data only, never the ground truth of the gaps); the parts live in
:mod:`torchfill.solvers.selection`, the measurements behind each rule in
experiments/results/auto.md and docs/real-gaps.md:

1. A hold-out ``V`` of observed samples shaped like the recording's own gaps (the gap pattern
   moved in time, the trial-end gaps mirrored onto the other trial end: :mod:`.selection.draws`).
   More draws are pooled (``draws``, and up to ``MAX_DRAWS`` until ``min_gaps`` held-out gaps),
   except where the first draw's held-out gaps take many distinct windows (``ENOUGH_WINDOWS``).
2. Every candidate (:mod:`.selection.candidates`) fits with ``V`` hidden and is scored on ``V``,
   through the ``post`` step ``fill()`` passes (its constraints), so candidates are scored on
   what ``fill()`` returns; held-out samples that rigid donors fill do not count. A candidate
   that fails on the recording is dropped (``dropped_``).
3. Each gap (real or held out) gets a kind (:mod:`.selection.kinds`: trial end or inside, its
   length, fast or not, filled by a partial candidate or not). Per kind, the candidates'
   held-out mean squared errors give the weights (:mod:`.selection.weights`: inverse-MSE weights
   over those within ``keep_ratio`` of the best, the model averaging of Tits et al. 2018; a kind
   seen in few held-out gaps leans on its parent), then on each gap a candidate that strays from
   the others counts less (``consensus``). With training recordings (``cross``), a trial-end
   kind also weighs the cross-trial hold-out (:mod:`.selection.cross`).
4. The candidates that carry weight on a real gap are refitted on every observed sample
   (``refit``), each reusing what its hold-out fit chose (:meth:`Solver.carry`), and the real
   gaps get the weighted average of the refits; on the trial-end kinds the PMA family's
   (``END_AVERAGE``) is the mean of its refit and its hold-out fill.
5. The error estimate ``std_`` (T, J): :mod:`.selection.error_model`.
6. A long recording's later windows (:mod:`torchfill.windows`) take the first window's choice
   (:meth:`Auto.carry`, the ``choice`` parameter): they fit only the candidates with weight, once,
   on their real gaps (a window that would try other candidates chooses for itself).

References
----------
Tits, Tilmanne & Dutoit, "Robust and automatic motion-capture data recovery using soft skeleton
constraints and model averaging", PLoS ONE 13(7): e0199744 (2018).
"""
from __future__ import annotations

from concurrent.futures import Future

import torch

from .. import ops
from .base import OneShotSolver, Param, available, register
from .selection import draws
from .selection.candidates import (DEFAULT_CANDIDATES, INTERIOR, PARTIAL, SESSION,  # noqa: F401
                                   Fits, default_names)
from .selection.cross import cross_holdout
from .selection.error_model import fit_std, mix2, sample_features
from .selection.kinds import N_BASE, N_KINDS, kind_name, sample_kinds
from .selection.weights import consensus, join_holes, kind_mse, kind_weights, mse_weights

Tensor = torch.Tensor

#: What a fit's choice holds (:meth:`Auto.carry`, the ``choice`` parameter).
CHOICE_KEYS = frozenset({"tried", "names", "weights", "mse", "error_model", "carried", "scores"})


@register
class Auto(OneShotSolver):
    """Per-gap choice and averaging of candidate methods from errors on gap-shaped hold-outs of
    the observed data, with an error estimate per filled sample (``std_``).

    Parameters
    ----------
    candidates : tuple of str, optional
        Registered method names to try (default ``DEFAULT_CANDIDATES``, those registered).
    candidate_params : dict, optional
        Hyperparameters per candidate, ``{name: {param: value}}``.
    combine : {"average", "select"}
        Per gap kind, inverse-MSE weighted average of the near-best candidates, or the best alone.
    keep_ratio : float
        ``average``: candidates whose held-out MSE is within this factor of the best take part.

    Attributes
    ----------
    std_ : Tensor (T, J)
        Estimated standard deviation of each coordinate's error at each filled sample, in the
        data's units; NaN where observed.
    scores_ : dict
        Held-out RMSE (normalized units, all held-out entries) per candidate that ran.
    weights_ : dict
        Per gap kind, the candidate weights used.
    cross_scores_ : dict
        With training data: RMSE (normalized units) per candidate on the cross-trial hold-out
        (:func:`~torchfill.solvers.selection.cross.cross_holdout`); empty where it did not run.
    cross_window_ : tuple of int or None
        The training recording (its index) and the start frame of the window the cross-trial
        hold-out was laid onto.
    anchored_ : Tensor (T, J) of bool
        Missing samples whose fill is at least half a partial candidate's (``rigid``: rebuilt
        from segment-mates); ``fill()``'s soft distances hold them still.
    """

    name = "auto"
    spatial = True
    finish_short_gaps = True
    fit_data = ("training", "post", "segments")
    params = {
        "candidates": Param(None, (tuple, list), allow_none=True,
                            doc="method names to try (None: DEFAULT_CANDIDATES that are registered)"),
        "candidate_params": Param(None, dict, allow_none=True,
                                  doc="hyperparameters per candidate, {name: {param: value}}"),
        "combine": Param("average", str, choices=("average", "select"),
                         doc="per gap kind: inverse-MSE average of the near-best candidates, or "
                             "the best alone"),
        "refit": Param(True, bool,
                       doc="refit the candidates that carry weight on all observed samples for the "
                           "real gaps (False: one fit per candidate, the hold-out fit fills them)"),
        "draws": Param(2, int, low=1,
                       doc="hold-out draws (shifts of the gap pattern) whose errors are pooled "
                           "for the weights, each a fit of every candidate"),
        "min_gaps": Param(40, int, low=0,
                          doc="draw again (up to MAX_DRAWS draws) until the pooled draws hold "
                              "out this many gaps: a recording with few gaps gets a thin "
                              "hold-out, whose draw decides the weights; one draw where its "
                              "held-out gaps take ENOUGH_WINDOWS distinct windows (0: exactly "
                              "``draws``)"),
        "cross": Param(True, bool,
                       doc="with training data: trial-end gap kinds scored by the geometric mean "
                           "of the recording's hold-out and the cross-trial hold-out's mean "
                           "squared errors (it needs a training recording as long as the "
                           "recording, and costs about one more round of fits)"),
        "choice": Param(None, dict, allow_none=True,
                        doc="an earlier window's choice of the same recording (its carry(): "
                            "candidates, weights per gap kind, error model): only the candidates "
                            "that carry weight are fitted, on the real gaps, with no hold-out "
                            "(a window that would try other candidates chooses for itself)"),
        "keep_ratio": Param(1.5, float, low=1.0,
                            doc="average: candidates within this factor of the best held-out MSE"),
    }

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        known = set(available())
        for name in self.candidates or ():
            base = name.removesuffix(SESSION) if isinstance(name, str) else name
            if not isinstance(name, str) or base not in known or base == self.name:
                raise ValueError(f"{self.name}: candidates expected registered method names "
                                 f"other than 'auto' (NAME{SESSION}: NAME with the training "
                                 f"data), found {name!r}")
        for name, p in (self.candidate_params or {}).items():
            if not isinstance(p, dict):
                raise ValueError(f"{self.name}: candidate_params expected {{name: dict}}, "
                                 f"found {name!r}: {p!r}")
        lacking = CHOICE_KEYS - set(self.choice or CHOICE_KEYS)
        if lacking:
            raise ValueError(f"{self.name}: choice expected an earlier fit's carry()['choice'], "
                             f"found a dict without {sorted(lacking)}")

    def candidate_names(self) -> list[str]:
        if self.candidates is not None:
            return list(self.candidates)
        return default_names(getattr(self, "Omega_", None),
                             getattr(self, "fit_data_", {}).get("training") is not None)

    # -- contract --------------------------------------------------------------------------
    def _initialize(self) -> None:
        self.X_ = self.interp_start()
        T, J = self.M_.shape[:2]
        self.std_ = torch.full((T, J), float("nan"), dtype=self.M_.dtype, device=self.M_.device)
        self.anchored_ = torch.zeros((T, J), dtype=torch.bool, device=self.M_.device)
        self.scores_: dict[str, float] = {}
        self.weights_: dict[str, dict[str, float]] = {}
        self.dropped_: dict[str, str] = {}
        self.carried_: dict[str, dict] = {}
        self.cross_scores_: dict[str, float] = {}
        self.cross_window_: tuple[int, int] | None = None
        self.error_model_: tuple | None = None

    def _estimate(self) -> Tensor:
        return self.X_

    def step(self) -> dict[str, float]:
        seen = self.Omega_.reshape(self.M_.shape[0], self.M_.shape[1], -1).all(dim=2)
        if bool(seen.all()):
            return {"delta": 0.0}
        self._fits = Fits(self.M_, self.mu_, self.sigma_, self.fit_data_, self.seed,
                          self.candidate_params, self.candidates, self.carried_, self.report)
        try:
            with self._fits.open_lanes():
                names = self._fill(seen)
        finally:
            self._fits = None
        return {"delta": 0.0, "candidates": float(len(names))}

    def _fill(self, seen: Tensor) -> list[str]:
        """The choice (or an earlier window's) and the combined fill; the candidates' names."""
        self.tried_ = self.candidate_names()        # once: the default's read the gap pattern
        if self.choice is not None and set(self.tried_) == set(self.choice["tried"]):
            V = torch.zeros_like(seen)
            names, fills, donor, W, mse = self._chosen(~seen)
        else:
            names, fills, donor, W, mse, V = self._choose(seen)
        self._combine(names, fills, donor, W, mse, V, seen)
        return names

    def _run(self, names: list[str], fit_missing: Tensor, behind: tuple = ()
             ) -> tuple[list[str], Tensor, dict]:
        """The candidates ``names`` fitted with ``fit_missing`` hidden (:meth:`Fits.run`), with
        those still running in ``behind`` NaN and their futures by index."""
        names, fills = self._fits.run(names, fit_missing, self.dropped_, behind)
        self._some_left(names)
        running = {c: f for c, f in enumerate(fills) if isinstance(f, Future)}
        nan = self.M_.new_full((*fit_missing.shape, self.M_.numel() // fit_missing.numel()),
                               torch.nan)
        fills = [nan if c in running else f for c, f in enumerate(fills)]
        return names, torch.stack(fills), running

    def _some_left(self, names: list[str]) -> None:
        """Refuse a recording on which every candidate failed, naming each one's error."""
        if not names:
            raise ValueError(f"{self.name}: every candidate failed on this recording: "
                             + "; ".join(f"{k}: {v}" for k, v in self.dropped_.items()))

    def _choose(self, seen: Tensor) -> tuple[list[str], Tensor, Tensor, Tensor, Tensor, Tensor]:
        """Steps 1-4 of the module notes: the hold-out ``V``, every candidate fitted with it
        hidden and scored per gap kind, the weights ``W`` (n_kinds, C), and (``refit``) the
        candidates with weight on a real gap refitted there. Returns the candidates' names, their
        fills (C, T, J, D: of ``V`` from the hold-out fits, of the real gaps from the refits),
        the (T, J) samples rigid donors fill, ``W``, each candidate's mean held-out squared
        error (C,) and ``V``."""
        V = draws.holdout(seen, self.generator_)
        fit_missing = ~seen | V
        names, fills, running = self._run(self.tried_, fit_missing, INTERIOR)
        donor = self._fits.post(fit_missing).donor                  # rigid-donor samples
        Xt = self.M_.reshape(self.M_.shape[0], self.M_.shape[1], -1)
        kinds = sample_kinds([n in PARTIAL for n in names], fills, fit_missing, Xt)[-1]
        first, err2 = draws.first_scores(fills, donor, kinds, Xt, V)
        pooled = draws.pooled(first, self._fits, names, seen, V, self.generator_, self.draws,
                              self.min_gaps)
        names, fills, err2, pooled = draws.settle_first(self._fits, names, fills, err2, pooled,
                                                        running, V, donor, self.dropped_)
        self._some_left(names)
        W = self._weights(names, seen, pooled, fills.dtype)
        if self.refit and bool(V.any()):
            w = W[kinds].permute(2, 0, 1)                           # (C, T, J)
            fills, real_donor = self._fits.refit(names, fills, w, ~seen, kinds % 2 == 1)
            donor = torch.where(V, donor, real_donor)
        self.scores_ = ({n: float(e.nanmean().sqrt()) for n, e in zip(names, err2)}
                        if err2.numel() else {})
        mse = (torch.nan_to_num(err2.nanmean(dim=1), nan=torch.inf) if err2.numel()
               else torch.ones(len(names), dtype=fills.dtype, device=fills.device))
        return names, fills, donor, W, mse, V

    def _weights(self, names: list[str], seen: Tensor, pooled: tuple, dtype) -> Tensor:
        """The weights (n_kinds, C) from the pooled draws' squared errors, kinds and gap ids,
        with the cross-trial hold-out on the trial-end kinds (``cross``)."""
        e_all, k_all, g_all = pooled
        allowed = torch.ones(N_KINDS, len(names), dtype=torch.bool, device=seen.device)
        allowed[:N_BASE, [c for c, n in enumerate(names) if n in PARTIAL]] = False
        cross = None
        if self.cross:
            cross, self.cross_window_, self.cross_scores_ = cross_holdout(self._fits, names, seen)
        if e_all.shape[1] == 0:                                     # nothing to choose on
            return allowed / allowed.sum(dim=1, keepdim=True).to(dtype)
        if cross is not None:
            Mo = kind_mse(e_all, k_all, g_all, N_KINDS, partial_from=N_BASE)
            Mc = kind_mse(*cross, N_KINDS, partial_from=N_BASE)
            end = (torch.arange(N_KINDS, device=Mo.device) % 2 == 1)[:, None]
            M = torch.where(end & ~torch.isnan(Mc), (Mo * Mc).sqrt(), Mo)
            return mse_weights(M, combine=self.combine, keep_ratio=self.keep_ratio,
                               allowed=allowed)
        return kind_weights(e_all, k_all, g_all, N_KINDS, combine=self.combine,
                            keep_ratio=self.keep_ratio, allowed=allowed, partial_from=N_BASE)

    def _combine(self, names: list[str], fills: Tensor, donor: Tensor, W: Tensor, mse: Tensor,
                 V: Tensor, seen: Tensor) -> None:
        """Step 5 of the module notes and the weighted average: the fills (C, T, J, D) of the
        real gaps and of ``V``, through the post-step, combined by the weights ``W`` of each
        sample's gap kind and :func:`consensus`; ``X_``, ``std_``, ``anchored_``, ``weights_``
        and ``choice_`` set. ``donor`` (T, J): the samples rigid donors fill; ``mse`` (C,): each
        candidate's held-out mean squared error (weights of the candidates' spread)."""
        fit_missing = ~seen | V
        Xt = self.M_.reshape(self.M_.shape[0], self.M_.shape[1], -1)
        partial = [n in PARTIAL for n in names]
        d, L, edge, motion, kinds = sample_kinds(partial, fills, fit_missing, Xt)
        w = W[kinds].permute(2, 0, 1)                               # (C, T, J)
        w = torch.where(torch.isfinite(fills).all(dim=-1), w, 0.0)  # a partial fill's NaN
        w = w / ops.clamp_tiny(w.sum(dim=0, keepdim=True))
        for part in (~seen, V):                   # real and held-out gaps alike, each on its own
            w = consensus(w, fills, part)
        partial = torch.tensor(partial, device=w.device)
        self.anchored_ = ~seen & (w[partial].sum(dim=0) >= 0.5)     # mostly a segment fill
        mean = (w[..., None] * torch.nan_to_num(fills)).sum(dim=0)
        mean = join_holes(mean, fills, w, partial, fit_missing)
        fills = torch.where(torch.isfinite(fills), fills, mean)     # no say where it has none
        share, spread2, bend2, speed2 = sample_features(fills, mean, mse, fit_missing, Xt)
        self.weights_ = {kind_name(k): {n: round(float(x), 4) for n, x in zip(names, W[k]) if x > 0}
                         for k in range(N_KINDS)}
        segment = kinds >= N_BASE                   # a partial (segment) candidate fills it
        self.error_model_, self.std_ = fit_std(
            V, seen, (d, L, edge, share, spread2, bend2, speed2, motion, donor | segment,
                      mix2(fills, mean, w)),
            ((mean - Xt) ** 2).mean(dim=2), self.error_model_, self.sigma_)
        est = torch.where(fit_missing[..., None], mean, Xt).reshape(self.M_.shape)
        self.X_ = torch.where(self.Omega_, self.M_, est)
        self.choice_ = {"tried": self.tried_, "names": list(names),
                        "weights": W.tolist(), "mse": mse.tolist(),
                        "error_model": self.error_model_, "carried": dict(self.carried_),
                        "scores": dict(self.scores_)}

    def _chosen(self, gaps: Tensor) -> tuple[list[str], Tensor, Tensor, Tensor, Tensor]:
        """An earlier window's choice (``choice``, see :meth:`carry`): the candidates that carry
        weight in some gap kind, fitted on all observed samples (each with the carry of its
        earlier fit), through the post-step. Returns their names, fills (C, T, J, D), the
        samples rigid donors fill, their weights (n_kinds, C) and held-out mean squared errors
        (C,). A kind left without weight by a candidate that fails here takes the candidate
        with the smallest held-out error among those allowed there."""
        c = self.choice
        W = torch.tensor(c["weights"], dtype=self.M_.dtype, device=self.M_.device)
        mse = torch.tensor(c["mse"], dtype=self.M_.dtype, device=self.M_.device)
        self.carried_.clear()                   # the same dict the fits read
        self.carried_.update({k: dict(v) for k, v in c["carried"].items()})
        self.scores_ = dict(c["scores"])
        self.error_model_ = c["error_model"]
        use = [i for i in range(len(c["names"])) if bool((W[:, i] > 0).any())]
        outs = list(self._fits.fit_all([c["names"][i] for i in use], gaps, "refit",
                                       then=self._fits.constrained(gaps)))
        for i, out in zip(list(use), outs):
            if isinstance(out, Exception):
                self.dropped_[c["names"][i]] = str(out)
                use.remove(i)
        if not use:
            raise ValueError(f"{self.name}: every chosen candidate failed on this window: "
                             + "; ".join(f"{k}: {v}" for k, v in self.dropped_.items()))
        names = [c["names"][i] for i in use]
        W, mse = W[:, use], mse[use]
        for k in torch.nonzero(W.sum(dim=1) <= 0).flatten().tolist():
            ok = [n not in PARTIAL or k >= N_BASE for n in names]
            W[k, int(torch.where(torch.tensor(ok, device=W.device), mse, torch.inf).argmin())] = 1.0
        fills = torch.stack([out for out in outs if not isinstance(out, Exception)])
        return names, fills, self._fits.post(gaps).donor, W, mse

    def carry(self) -> dict:
        """The choice (candidates, weights per gap kind, error model): the next windows of the
        same recording fit only the candidates that carry weight, on their real gaps, with no
        hold-out (see docs/speed.md)."""
        choice = self.choice if self.choice is not None else getattr(self, "choice_", None)
        return {"choice": choice} if choice is not None else {}

    def _holdout(self, seen: Tensor) -> Tensor:
        """The first draw's held-out samples (:func:`~.selection.draws.holdout`)."""
        return draws.holdout(seen, self.generator_)
