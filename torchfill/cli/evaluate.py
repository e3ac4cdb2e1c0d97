"""``torchfill evaluate IN``: gaps simulated on observed samples, each method scored."""
from __future__ import annotations

import json
import warnings

from .names import check_params, method_names
from .options import _naming, _parse_params, _pose_options, _progress, _say


def _cmd_evaluate(args) -> int:
    import numpy as np

    import torchfill
    from torchfill import gaps, metrics

    src = f"{args.input}: "
    methods = method_names(args.method, src) or \
        ["linear", "spline", "pchip", torchfill.default_method()]
    params = check_params(methods, _parse_params(args.param), src)     # before any work
    read = torchfill.read(args.input, **_pose_options(args))
    truth = read.merge_duplicates()
    T, J = truth.points.shape[:2]
    kwargs = _protocol_kwargs(args, J)
    # gaps are simulated on observed samples of every marker (real files are rarely complete)
    mask = gaps.generate(args.protocol, T, J, seed=args.seed, **kwargs) & ~truth.mask
    if not mask.any():
        raise ValueError(f"{args.input}: no observed sample falls in the simulated gaps")
    incomplete = truth.with_points(np.where(mask[..., None], np.nan, truth.points))
    merged = read.n_markers - truth.n_markers
    _say(args, f"{truth}" + (f"  ({merged} duplicate-label marker(s) merged)" if merged else "")
         + f"\nprotocol {args.protocol} {kwargs} seed {args.seed}: {int(mask.sum())} observed "
         f"samples hidden in {int(mask.any(axis=0).sum())} markers")
    from torchfill.sequence import UNITS_PER_MM          # errors are reported in mm

    factor, units = ((1.0 / UNITS_PER_MM[truth.units], "mm") if truth.units in UNITS_PER_MM
                     else (1.0, truth.units))
    rows, said = [], {}
    for method in methods:
        with _naming(args.input), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")     # scored everywhere: no extrapolation limit
            filled = torchfill.fill(incomplete, method, progress=_progress(args),
                                    extrapolate=None, params=params[method])
        for w in caught:
            said.setdefault((w.category, _headline(str(w.message))), (w, []))[1].append(method)
        info = filled.meta["fill_info"]
        errors = metrics.score(filled.points, np.nan_to_num(truth.points), mask)
        rows.append({"method": method, **{k: v * factor for k, v in errors.items()},
                     "seconds": info["seconds"],
                     "iterations": info["n_iter"] if _iterative(method) else None})
    for w, where in said.values():              # each warning once, with the fills that gave it
        also = f" (the fills of {', '.join(dict.fromkeys(where))})" if len(methods) > 1 else ""
        warnings.warn_explicit(f"{w.message}{also}", w.category, w.filename, w.lineno)
    if args.json:
        print(json.dumps({"file": str(args.input), "protocol": args.protocol, **kwargs,
                          "seed": args.seed, "units": units, "results": rows,
                          "best": _best(rows, units, torchfill.default_method())}, indent=2))
    else:
        print(_table(rows, units))
        print(_best(rows, units, torchfill.default_method()))
    return 0


def _iterative(method: str) -> bool:
    from torchfill.solvers import base

    return bool(getattr(base._REGISTRY[method], "iterative", True))


def _headline(message: str) -> str:
    """A warning's text up to its first colon outside parentheses (its counts follow)."""
    depth = 0
    for i, ch in enumerate(message):
        depth += (ch == "(") - (ch == ")")
        if ch == ":" and depth == 0:
            return message[:i]
    return message


def _best(rows: list[dict], units: str, default: str) -> str:
    """One line: the method with the smallest error over the simulated gaps and its margin."""
    ranked = sorted(rows, key=lambda r: r["rmse_missing"])
    best = ranked[0]
    line = f"best on this file: {best['method']} (rmse over the gaps {best['rmse_missing']:.4g} {units}"
    if len(ranked) > 1:
        other = ranked[1]
        gap = other["rmse_missing"] - best["rmse_missing"]
        line += (f", {gap:.3g} {units} ({100 * gap / other['rmse_missing']:.0f} %) below "
                 f"{other['method']}")
    mine = next((r for r in rows if r["method"] == default), None)
    if mine is not None and default not in (best["method"], ranked[1]["method"] if len(ranked) > 1
                                            else None):
        line += (f"; the default {default}: {mine['rmse_missing']:.4g}, "
                 f"{mine['rmse_missing'] - best['rmse_missing']:.3g} {units} more")
    elif mine is not None and default == best["method"]:
        line += "; it is the default"
    return line + ")"


def _protocol_kwargs(args, J: int) -> dict:
    n_markers = min(args.markers, J)
    table = {
        "multi_gap": dict(n_markers=n_markers, gap_length=args.gap_length, max_gaps=args.max_gaps),
        "shared_window": dict(n_markers=n_markers, gap_length=args.gap_length),
        "continuous_runs": dict(n_markers=n_markers, gap_length=args.gap_length),
        "evenly_spaced": dict(n_gaps=args.max_gaps, gap_length=args.gap_length),
        "blackout": dict(gap_length=args.gap_length),
        "random_entries": dict(rate=args.rate),
    }
    return table[args.protocol]


def _table(rows: list[dict], units: str) -> str:
    cols = ["rmse", "ave", "std", "rmse_missing", "gap_error", "seconds", "iterations"]
    head = f"{'method':<12}" + "".join(f"{c:>14}" for c in cols)
    lines = [f"errors in {units}; rmse/ave/std over all entries (observed count as 0), "
             "rmse_missing over the gaps, gap_error = mean 3-D (2-D) error per gap", head, "-" * len(head)]
    for row in rows:
        lines.append(f"{row['method']:<12}" + "".join(
            f"{row[c]:>14.4g}" if c != "iterations" else
            f"{'-' if row[c] is None else row[c]:>14}" for c in cols))
    return "\n".join(lines)
