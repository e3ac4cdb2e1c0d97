"""``torchfill evaluate IN``: gaps simulated on observed samples, each method scored."""
from __future__ import annotations

import json

from .options import _naming, _parse_params, _pose_options, _progress, _say


def _cmd_evaluate(args) -> int:
    import numpy as np

    import torchfill
    from torchfill import gaps, metrics

    read = torchfill.read(args.input, **_pose_options(args))
    truth = read.merge_duplicates()
    T, J = truth.points.shape[:2]
    kwargs = _protocol_kwargs(args, J)
    # gaps are simulated on observed samples of every marker (real files are rarely complete)
    mask = gaps.generate(args.protocol, T, J, seed=args.seed, **kwargs) & ~truth.mask
    if not mask.any():
        raise ValueError(f"{args.input}: no observed sample falls in the simulated gaps")
    incomplete = truth.with_points(np.where(mask[..., None], np.nan, truth.points))
    methods = [m for part in args.method for m in part.split(",") if m] or \
        ["linear", "spline", "pchip", torchfill.default_method()]
    merged = read.n_markers - truth.n_markers
    _say(args, f"{truth}" + (f"  ({merged} duplicate-label marker(s) merged)" if merged else "")
         + f"\nprotocol {args.protocol} {kwargs} seed {args.seed}: {int(mask.sum())} observed "
         f"samples hidden in {int(mask.any(axis=0).sum())} markers")
    factor, units = _MM.get(truth.units, (1.0, truth.units))
    rows = []
    for method in dict.fromkeys(methods):
        params = _parse_params(args.param) if len(methods) == 1 else {}
        with _naming(args.input):   # scored everywhere: no extrapolation limit
            filled = torchfill.fill(incomplete, method, progress=_progress(args),
                                    extrapolate=None, params=params)
        info = filled.meta["fill_info"]
        errors = metrics.score(filled.points, np.nan_to_num(truth.points), mask)
        rows.append({"method": method, **{k: v * factor for k, v in errors.items()},
                     "seconds": info["seconds"], "iterations": info["n_iter"]})
    if args.json:
        print(json.dumps({"file": str(args.input), "protocol": args.protocol, **kwargs,
                          "seed": args.seed, "units": units, "results": rows}, indent=2))
    else:
        print(_table(rows, units))
    return 0


#: Errors are reported in mm: factor from the file's units.
_MM = {"mm": (1.0, "mm"), "m": (1000.0, "mm"), "cm": (10.0, "mm")}


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
            f"{row[c]:>14.4g}" if c != "iterations" else f"{row[c]:>14d}" for c in cols))
    return "\n".join(lines)
