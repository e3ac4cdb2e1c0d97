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
__all__ = ["FileFormatError", "UnfilledWarning", "MarkerSequence", "default_method", "fill", "methods", "read", "score", "write"]

#: Public names and their modules (imported on first access; ``filling`` imports torch).
_LAZY = {"fill": "filling", "methods": "filling", "default_method": "filling",
         "UnfilledWarning": "filling", "FileFormatError": "io", "read": "io", "write": "io",
         "score": "metrics", "MarkerSequence": "sequence"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
