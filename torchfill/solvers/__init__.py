"""Solvers and their registry. Importing this package registers every method."""
from importlib import import_module

from .base import NotConvergedWarning, Param, Solver, available, get_solver, register

# One module per family; each registers its methods on import. (Modules not written yet are
# skipped while the families land in parallel; see the issues.)
for _module in ("interp", "matrix", "pca", "tucker", "cp", "autograd", "completion", "spc",
                "gloersen", "pma", "rigid",
                "auto"):
    try:
        import_module(f"{__name__}.{_module}")
    except ModuleNotFoundError as _err:
        if _err.name != f"{__name__}.{_module}":
            raise

__all__ = ["NotConvergedWarning", "Param", "Solver", "available", "get_solver", "register"]
