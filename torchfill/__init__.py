"""torchfill: fill gaps in motion-capture marker data with low-rank tensor and matrix methods.

>>> import torchfill
>>> seq = torchfill.read("trial.c3d")
>>> out = torchfill.fill(seq, method="tucker_tnn")
>>> torchfill.write(out, "trial_filled.c3d")
"""
from .filling import UnfilledWarning, default_method, fill, methods
from .io import FileFormatError, read, write
from .metrics import score
from .sequence import MarkerSequence
from .solvers import NotConvergedWarning, Solver, get_solver

__version__ = "0.1.0"
__all__ = ["FileFormatError", "MarkerSequence", "NotConvergedWarning", "Solver", "UnfilledWarning",
           "default_method", "fill", "get_solver", "methods", "read", "score", "write"]
