"""Method and hyperparameter names of the command line, checked before any work: case and ``-``
forgiven, a "did you mean" for a typo."""
from __future__ import annotations

import difflib
import warnings

from .terminal import _one_line


def method_names(values, src: str = "") -> list[str]:
    """The registered names of ``-m`` values (repeatable, comma-separated), in order, once each."""
    from torchfill._catalog import resolve

    names = []
    for value in values:
        for part in filter(None, (p.strip() for p in str(value).split(","))):
            try:
                names.append(resolve(part))
            except ValueError as err:
                raise ValueError(f"{src}{err}") from None
    return list(dict.fromkeys(names))


def check_params(methods: list[str], params: dict, src: str = "") -> dict[str, dict]:
    """``-p`` hyperparameters per method: each name must be one of the methods' own (a "did you
    mean" otherwise); it goes to the methods that declare it, whose checks judge its value."""
    from torchfill.solvers import base

    declared = {m: [*base._REGISTRY[m].declared_params(), *base._REGISTRY[m]._merged("renamed")]
                for m in methods}
    known = list(dict.fromkeys(k for keys in declared.values() for k in keys))
    for key in params:
        if key not in known:
            close = difflib.get_close_matches(key, known, n=1)
            owner = methods[0] if len(methods) == 1 else ", ".join(methods)
            hint = f"; did you mean {close[0]!r}?" if close else _elsewhere(key)
            raise ValueError(f"{src}{owner}: no hyperparameter {key!r}{hint}"
                             " ('torchfill methods -v' lists them)")
    per_method = {m: {k: v for k, v in params.items() if k in declared[m]} for m in methods}
    for method, own in per_method.items():
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                base.get_solver(method, **own)
        except (ValueError, TypeError) as err:
            raise ValueError(f"{src}{_one_line(err)}") from None
    return per_method


def _elsewhere(key: str) -> str:
    """A close name that other methods take (e.g. ``max_iter``: the iterative ones), or ''."""
    from torchfill.solvers import base

    owners: dict[str, list[str]] = {}
    for name in base.available():
        for k in base._REGISTRY[name].declared_params():
            owners.setdefault(k, []).append(name)
    close = difflib.get_close_matches(key, list(owners), n=1)
    if not close:
        return ""
    some = owners[close[0]]
    return (f"; {close[0]!r} is a hyperparameter of {', '.join(some[:4])}"
            + (f" and {len(some) - 4} more" if len(some) > 4 else ""))
