"""Lightning drivers for the solvers and the experiment runner (see ``experiments/README.md``).

* :class:`SolverModule` wraps any registered solver: one ``training_step`` = one solver step;
* :class:`CaseDataModule` serves one case (the incomplete tensor and mask; the truth stays inside);
* callbacks: :class:`Convergence` (observed data only), :class:`HistoryLogger`, :class:`Evaluation`
  (truth-based metrics, for evaluation only);
* :func:`run_experiment` runs a YAML config end to end (:mod:`.runner`: plan -> execute -> report).

Needs the ``[experiments]`` extra (Lightning, PyYAML, matplotlib): ``pip install
'torchfill[experiments]'``. ``import torchfill`` and ``torchfill fill`` never import this package.
"""
#: What ``pip install 'torchfill[experiments]'`` adds, by import name.
EXTRA = ("pytorch_lightning", "yaml", "matplotlib")
try:
    import matplotlib  # noqa: F401
    import pytorch_lightning  # noqa: F401
    import yaml  # noqa: F401
except ImportError as _err:
    raise ImportError(f"torchfill experiment needs the [experiments] extra ({_err.name or _err} "
                      "is not installed): pip install 'torchfill[experiments]'") from None
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
