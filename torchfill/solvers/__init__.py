"""Solvers and their registry. Importing this package registers every method.

This package's face is what the layers above use: the registry (:func:`available`,
:func:`get_solver`), the contract (:class:`Solver`, :class:`Param`) and the two pieces of solver
work that ``fill()`` asks for by name: segments as marker indices and the placement of
never-observed markers from training recordings.
"""
from importlib import import_module

from .base import (NotConvergedWarning, OneShotSolver, Param, Solver, available, get_solver,
                   register)

#: One module per family, in registration order (``torchfill methods`` lists them so, read from
#: here without importing them); each registers its methods on import.
FAMILIES = ("interp", "matrix", "pca", "tucker", "cp", "autograd", "completion", "spc",
            "gloersen", "pma", "rigid", "auto")
for _family in FAMILIES:
    import_module(f"{__name__}.{_family}")
del _family

from .placement import place_from_training  # noqa: E402 (after the families: registration order)
from .rigid import index_segments  # noqa: E402

__all__ = ["NotConvergedWarning", "OneShotSolver", "Param", "Solver", "available", "get_solver",
           "index_segments", "place_from_training", "register"]
