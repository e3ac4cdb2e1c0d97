"""The command line's ``fill()`` options, read from the arguments and checked before any file is read."""
from __future__ import annotations

import ast
import json
import sys
from contextlib import contextmanager
from pathlib import Path

from .terminal import _one_line


def _fill_options(args, src):
    """The command line's :class:`~torchfill.options.FillOptions`, checked before any file is
    read: method name and ``-p`` names with a "did you mean", values by the method's own checks
    and the options' own."""
    from torchfill.options import FillOptions

    from .names import check_params, method_names

    src = f"{src}: " if src is not None else ""
    if args.max_gap is not None and args.max_gap < 0:
        raise ValueError(f"{src}max_gap expected >= 0, found {args.max_gap}")
    params = _parse_params(args.param)
    _extrapolate(args)
    if args.method is not None:                 # a typo: say so before torch
        named = method_names([args.method], src)
        if not named:
            raise ValueError(f"{src}-m expected a method name, found {args.method!r}")
        args.method = named[0]
    import torchfill
    from torchfill.solvers import base

    names = torchfill.methods()
    method = torchfill.default_method() if args.method is None else args.method
    cls = base._REGISTRY[method]
    declared = [*cls.declared_params(), *cls._merged("renamed")]
    for key in params:
        if key in _fill_option_names() and key not in declared:   # pma's own window: -p window=
            raise ValueError(f"{src}-p {key}: a fill option, give it as --{key.replace('_', '-')}")
    check_params([method], params, src)
    if (args.training or getattr(args, "session", False)) and "training" not in cls.fit_data:
        takes = [m for m in names if "training" in base._REGISTRY[m].fit_data]
        raise ValueError(f"{src}{method} takes no training data; methods that do: "
                         f"{', '.join(takes)}")
    options = _window(args) | _dtype(args) | _extrapolate(args) | _segments(args)
    try:
        return FillOptions.make(method, params=params, max_gap=args.max_gap,
                                constraints=args.constraints, **options)
    except ValueError as err:
        raise ValueError(f"{src}{_one_line(err)}") from None


def _fill_option_names() -> set[str]:
    """``fill()``'s own options (not the method's hyperparameters)."""
    from dataclasses import fields

    from torchfill.options import FillOptions

    return {f.name for f in fields(FillOptions)} - {"method", "params"}


def _extrapolate(args) -> dict:
    """``fill()``'s ``extrapolate`` from ``--extrapolate`` (seconds, or ``none``: no limit)."""
    value = getattr(args, "extrapolate", None)
    if value is None:
        return {}
    if value.strip().lower() in ("none", "off", "inf"):
        return {"extrapolate": None}
    try:
        seconds = float(value)
    except ValueError:
        seconds = -1.0
    if not seconds >= 0:
        raise ValueError(f"--extrapolate expected seconds >= 0 or 'none', found {value!r}")
    return {"extrapolate": seconds}


def _segments(args) -> dict:
    """``fill()``'s ``segments`` from ``--segments`` (a YAML file, 'names' or 'data'), read
    now so that a bad file stops the run before any work."""
    value = getattr(args, "segments", None)
    if value is None:
        return {}
    if value in ("names", "data", "auto"):
        return {"segments": value}
    from torchfill.segments import load
    return {"segments": load(value)}


def _dtype(args) -> dict:
    """``fill()``'s ``dtype`` from ``--dtype`` (unset: the method's own)."""
    return {"dtype": args.dtype} if args.dtype else {}


def _window(args) -> dict:
    """``fill()``'s ``window`` from ``--window`` (0: the whole recording at once; unset: default)."""
    if args.window is None:
        return {}
    if args.window < 0 or args.window == 1:
        raise ValueError(f"--window expected 0 or a number of frames >= 2, found {args.window}")
    return {"window": args.window or None}


def _pose_options(args, path=None) -> dict:
    """Reader options of OpenPose folders (``--min-confidence``); an error for other inputs."""
    value = getattr(args, "min_confidence", None)
    if value is None:
        return {}
    path = path if path is not None else args.input
    path = path[0] if isinstance(path, list) else path
    if not Path(path).is_dir():
        raise ValueError(f"{path}: --min-confidence applies to OpenPose folders only")
    return {"min_confidence": value}


def _parse_params(pairs: list[str]) -> dict:
    """``NAME=VALUE`` pairs; VALUE as JSON (``true``, ``[8, 8, 3]``) or a Python literal as
    ``methods -v`` shows defaults (``True``, ``(8, 8, 3)``, ``None``), else a string."""
    params = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--param expected NAME=VALUE, found {pair!r}")
        try:
            params[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            try:
                params[key.strip()] = ast.literal_eval(value.strip())
            except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
                params[key.strip()] = value
    return params


@contextmanager
def _naming(path):
    """Errors about the input (too few frames, unknown method or hyperparameter...) name it."""
    try:
        yield
    except ValueError as err:
        if str(path) in str(err):
            raise
        raise ValueError(f"{path}: {_one_line(err)}") from None


def _say(args, text: str) -> None:
    if not getattr(args, "quiet", False):
        print(text, file=sys.stderr if getattr(args, "json", False) else sys.stdout)


def _progress(args) -> bool:
    """A fill's bar (percent, time left; see torchfill.progress) on a terminal, unless -q. Not
    on a terminal the command's own summary line is the only report."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()
