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

__version__ = "0.1.0"
__all__ = ["FileFormatError", "UnfilledWarning", "MarkerSequence", "default_method", "fill", "methods", "read", "score", "write"]
