"""A LightningModule that drives any registered solver, one solver step per ``training_step``.

Closed-form solvers update under ``torch.no_grad()`` inside ``step()``; autograd solvers take their
own optimizer step inside ``step()``. Both therefore run through Lightning's manual optimization
(``automatic_optimization = False``) on one path: ``training_step`` = ``solver.step_and_record()``.
"""
from __future__ import annotations

import logging
import time
import warnings

import pytorch_lightning as pl
import torch

from ..solvers.base import Solver


def observed_view(batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """What a solver may see of a batch: ``X`` with NaN at every masked sample, and the mask.

    Only the keys ``X`` and ``mask`` are read (anything else in the batch, e.g. a truth tensor put
    there by mistake, is ignored), and the masked samples of ``X`` are overwritten with NaN in a new
    tensor, so even an ``X`` carrying the truth at the gaps cannot leak it.
    """
    X, mask = batch["X"], torch.as_tensor(batch["mask"], dtype=torch.bool)
    if mask.shape != X.shape[:2]:
        raise ValueError(f"batch mask expected shape {tuple(X.shape[:2])}, found {tuple(mask.shape)}")
    nan = torch.full((), torch.nan, dtype=X.dtype, device=X.device)
    return torch.where(mask.reshape(mask.shape + (1,) * (X.ndim - 2)), nan, X), mask


class SolverModule(pl.LightningModule):
    """Wrap ``solver``; the first batch initializes it, every batch runs one step.

    Attributes
    ----------
    solve_seconds : float
        Time spent inside the solver (``initialize`` + every ``step_and_record``), excluding
        Lightning's and the callbacks' overhead.
    """

    def __init__(self, solver: Solver, data: dict | None = None) -> None:
        super().__init__()
        self.automatic_optimization = False
        self.solver = solver
        self.data = dict(data or {})          # the solver's fit data (e.g. auto's ``post``)
        self.initialized = False
        self.solve_seconds = 0.0
        self.X_obs: torch.Tensor | None = None

    def configure_optimizers(self):
        return None  # the solver updates itself (closed form, or its own optimizer in step())

    def training_step(self, batch: dict, batch_idx: int):
        start = time.perf_counter()
        if not self.initialized:
            self.X_obs, mask = observed_view(batch)
            self.solver.initialize(self.X_obs, mask, **self.data)
            self.initialized = True
        self.solver.step_and_record()
        self.solve_seconds += time.perf_counter() - start
        if self.solver.history_:   # wall time inside the solver so far, for loss-vs-time curves
            self.solver.history_[-1].setdefault("time_s", self.solve_seconds)
        return None

    def on_train_end(self) -> None:
        """The solver's end-of-fit hook (e.g. restoring a held-out best iterate), as ``fit`` does."""
        if self.initialized:
            self.solver.finalize()

    def filled(self) -> torch.Tensor:
        """The incomplete input with its gaps filled by the current estimate."""
        return self.solver.transform(self.X_obs)

    def done(self) -> bool:
        return self.initialized and (self.solver.converged_ or self.solver.n_iter_ >= self.solver.max_iter)


def quiet_lightning() -> None:
    """Silence Lightning's start-up chatter and its warnings that do not apply to solver fits."""
    for name in ("pytorch_lightning", "lightning_fabric", "lightning.pytorch", "lightning.fabric"):
        logging.getLogger(name).setLevel(logging.ERROR)
    for text in (".*does not have many workers.*", ".*returned `None`.*", ".*no optimizer.*",
                 ".*number of training batches.*", ".*GPU available but not used.*",
                 ".*TPU available.*", ".*LightningModule.configure_optimizers.*",
                 ".*`training_step` returned `None`.*", ".*log_every_n_steps.*",
                 ".*LeafSpec.*", ".*exists and is not empty.*", ".*in eval mode at the start.*"):
        warnings.filterwarnings("ignore", message=text)


def fit(solver: Solver, datamodule, *, callbacks=(), logger=False, progress: bool = False,
        accelerator: str = "cpu", data: dict | None = None) -> SolverModule:
    """Run ``solver`` on ``datamodule``'s case under a Lightning ``Trainer``; returns the module.

    The Trainer runs one epoch of ``datamodule.n_steps`` batches (set it to ``solver.max_iter``);
    :class:`~torchfill.lightning.callbacks.Convergence` ends it when the solver's own stopping rule
    fires (observed data only). ``data``: the solver's fit data besides X and the mask.
    """
    from .callbacks import Convergence

    quiet_lightning()
    module = SolverModule(solver, data)
    callbacks = list(callbacks)
    if not any(isinstance(c, Convergence) for c in callbacks):
        callbacks.insert(0, Convergence())
    trainer = pl.Trainer(max_epochs=1, accelerator=accelerator, devices=1, logger=logger,
                         callbacks=callbacks, enable_progress_bar=progress,
                         enable_checkpointing=False, enable_model_summary=False,
                         num_sanity_val_steps=0, log_every_n_steps=1)
    trainer.fit(module, datamodule=datamodule)
    return module
