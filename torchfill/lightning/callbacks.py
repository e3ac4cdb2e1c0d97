"""Callbacks for solver fits: stopping (observed data only), history logging, and evaluation.

:class:`Convergence` and :class:`HistoryLogger` see only what the solver records from observed data.
:class:`Evaluation` is the one place that compares with the ground truth, for reporting only: it
reads the truth from the DataModule, never hands anything back to the solver, and nothing it
computes influences when the fit stops.
"""
from __future__ import annotations

import math

import numpy as np
import pytorch_lightning as pl

from .. import metrics


class Convergence(pl.Callback):
    """Stop when the solver's own rule fires (``converged_``) or after ``max_iter`` steps.

    Optionally also stop early when the observed-data diagnostic ``monitor`` (a key of the solver's
    history, e.g. ``"objective"``) has not decreased by ``min_delta`` (relative) for ``patience``
    steps.
    """

    def __init__(self, monitor: str | None = None, patience: int = 0, min_delta: float = 0.0) -> None:
        self.monitor, self.patience, self.min_delta = monitor, patience, min_delta
        self.best, self.wait = math.inf, 0
        self.reason = ""

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        solver = pl_module.solver
        if solver.converged_:
            self.reason = "converged"
        elif solver.n_iter_ >= solver.max_iter:
            self.reason = "max_iter"
        elif self.monitor and self.patience and self._stalled(solver.history_[-1]):
            self.reason = f"{self.monitor} stalled"
        if self.reason:
            trainer.should_stop = True

    def _stalled(self, info: dict) -> bool:
        value = info.get(self.monitor)
        if value is None:
            return False
        if value < self.best - self.min_delta * abs(self.best if math.isfinite(self.best) else 0):
            self.best, self.wait = value, 0
        else:
            self.wait += 1
        return self.wait >= self.patience


class HistoryLogger(pl.Callback):
    """Send each step's history record (objective, ranks, delta: observed data) to the loggers."""

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if trainer.loggers:
            info = dict(pl_module.solver.history_[-1])
            step = int(info.pop("iter"))
            for logger in trainer.loggers:
                logger.log_metrics(info, step=step)


class Evaluation(pl.Callback):
    """Evaluation only: metrics of the filled tensor against the truth held by the DataModule.

    At the end of the fit ``final`` holds ``metrics.score`` of the result and ``filled`` the filled
    tensor (NumPy). With ``every=k > 0`` it also records ``curve``: the truth-based metrics every
    k-th step, for convergence plots. None of this goes back to the solver or its stopping rule.
    """

    def __init__(self, every: int = 0, curve_metrics=("rmse", "rmse_missing")) -> None:
        self.every, self.curve_metrics = every, tuple(curve_metrics)
        self.curve: list[dict[str, float]] = []
        self.final: dict[str, float] = {}
        self.filled: np.ndarray | None = None

    def _score(self, trainer, pl_module):
        dm = trainer.datamodule
        filled = pl_module.filled().detach().cpu().numpy()
        truth = dm.evaluation_truth().cpu().numpy()
        return filled, metrics.score(filled, truth, dm.mask.cpu().numpy())

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        n = pl_module.solver.n_iter_
        if self.every and (n % self.every == 0 or pl_module.done()):
            dm = trainer.datamodule
            filled = pl_module.filled().detach().cpu().numpy()
            truth, mask = dm.evaluation_truth().cpu().numpy(), dm.mask.cpu().numpy()
            self.curve.append({"iter": n, **{k: getattr(metrics, k)(filled, truth, mask)
                                             for k in self.curve_metrics}})

    def on_train_end(self, trainer, pl_module) -> None:
        if pl_module.initialized:
            self.filled, self.final = self._score(trainer, pl_module)
