"""torchfill: fill gaps in motion-capture marker data with low-rank tensor and matrix methods.

>>> import torchfill
>>> seq = torchfill.read("trial.c3d")
>>> out = torchfill.fill(seq, method="tucker_tnn")
>>> torchfill.write(out, "trial_filled.c3d")

Importing the package is cheap: reading, writing and scoring need only NumPy, and the names that
need torch (``fill``, ``methods`` ...) are imported on first use (PEP 562), so ``torchfill --help``
and ``torchfill info`` start without torch. Lightning is imported only by the experiment runner.
"""
from importlib import import_module

from .io import FileFormatError, read, write
from .metrics import score
from .sequence import MarkerSequence

__version__ = "0.1.0"
__all__ = ["FileFormatError", "UnfilledWarning", "MarkerSequence", "default_method", "fill", "methods", "read", "score", "write"]

#: Public names whose module imports torch, and that module (imported on first access).
_LAZY = {"fill": "filling", "methods": "filling", "default_method": "filling",
         "UnfilledWarning": "filling"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
