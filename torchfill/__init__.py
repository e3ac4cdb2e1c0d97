"""torchfill: fill gaps in motion-capture marker data with low-rank tensor and matrix methods.

>>> import torchfill
>>> seq = torchfill.read("trial.c3d")
>>> out = torchfill.fill(seq, method="tucker_tnn")
>>> torchfill.write(out, "trial_filled.c3d")

Importing the package is cheap: every public name is imported on first use (PEP 562), so
``torchfill --help`` imports neither NumPy nor torch, and ``torchfill info`` (reading needs only
NumPy) starts without torch. Lightning is imported only by the experiment runner.
"""
from importlib import import_module

__version__ = "0.1.0"
__all__ = ["FileFormatError", "FillOptions", "MarkerSequence", "NotConvergedWarning", "Solver",
           "UnfilledWarning", "default_method", "fill", "get_solver", "methods", "read", "score",
           "write"]

#: Where each public name lives. They are imported on first use (PEP 562), so ``import
#: torchfill.cli`` stays light and a Ctrl-C during the heavy imports (torch) reaches the CLI's
#: handler instead of printing a traceback.
_HOMES = {"fill": ".filling", "methods": ".filling", "default_method": ".options",
          "FillOptions": ".options", "UnfilledWarning": ".unfilled", "read": ".io", "write": ".io", "FileFormatError": ".io",
          "score": ".metrics", "MarkerSequence": ".sequence",
          "NotConvergedWarning": ".solvers", "Solver": ".solvers", "get_solver": ".solvers"}


_SUBMODULES = {"cli", "data", "filling", "gaps", "io", "lightning", "metrics", "ops", "options",
               "runtime", "segments", "sequence", "solvers", "constraints", "qc", "windows",
               "batch"}


def __getattr__(name: str):
    if name in _SUBMODULES:                # ``torchfill.io`` etc. after a bare ``import torchfill``
        return import_module(f".{name}", __name__)
    if name not in _HOMES:
        raise AttributeError(f"module 'torchfill' has no attribute {name!r}")
    value = getattr(import_module(_HOMES[name], __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
