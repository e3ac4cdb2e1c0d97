"""Lightning drivers for the solvers and the experiment runner (see ``experiments/README.md``).

* :class:`SolverModule` wraps any registered solver: one ``training_step`` = one solver step;
* :class:`CaseDataModule` serves one case (the incomplete tensor and mask; the truth stays inside);
* callbacks: :class:`Convergence` (observed data only), :class:`HistoryLogger`, :class:`Evaluation`
  (truth-based metrics, for evaluation only);
* :func:`run_experiment` runs a YAML config end to end.
"""
from .callbacks import Convergence, Evaluation, HistoryLogger
from .config import Case, Config, Method, load_config
from .data import CaseDataModule, Recording, load_recording
from .module import SolverModule, fit, observed_view


def __getattr__(name):  # the runner loads lazily, so ``python -m torchfill.lightning.runner`` is clean
    if name in ("main", "run_case", "run_experiment"):
        from . import runner

        return getattr(runner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Case", "CaseDataModule", "Config", "Convergence", "Evaluation", "HistoryLogger",
           "Method", "Recording", "SolverModule", "fit", "load_config", "load_recording", "main",
           "observed_view", "run_case", "run_experiment"]
