"""Command line: ``torchfill fill | evaluate | info | methods | experiment`` (also ``python -m torchfill``).

Every failure on bad input prints one line, ``torchfill: error: <file>: <problem>``, and exits
with status 2; nothing is written unless the whole fill succeeded.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

EXIT_ERROR = 2


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return EXIT_ERROR
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            status = args.run(args)
        for w in caught:
            if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning)):
                print(f"torchfill: warning: {w.message}", file=sys.stderr)
        return status
    except KeyboardInterrupt:
        print("torchfill: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError, KeyError) as err:
        print(f"torchfill: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as err:  # a bug, not bad input: still one line unless debugging
        if os.environ.get("TORCHFILL_DEBUG"):
            raise
        print(f"torchfill: internal error: {type(err).__name__}: {_one_line(err)} "
              "(set TORCHFILL_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


# -- sub-commands --------------------------------------------------------------------------------
def _cmd_fill(args) -> int:
    import torchfill

    seq = torchfill.read(args.input)
    out_path = Path(args.output) if args.output else _default_output(Path(args.input))
    params = _parse_params(args.param)
    if args.training:
        params["training"] = [torchfill.read(path) for path in args.training]
    method = args.method or torchfill.default_method()
    n_missing = int(seq.mask.sum())
    _say(args, f"{seq}\nfilling {n_missing} missing samples with {method} ...")
    filled = torchfill.fill(seq, method, max_gap=args.max_gap, progress=_progress(args),
                            return_std=bool(args.std), **params)
    filled = filled[0] if args.std else filled
    _clear_progress(args)
    torchfill.write(filled, out_path)
    if args.std:
        _write_std(filled, Path(args.std))
    info = filled.meta["fill_info"]
    left = int(filled.mask.sum())
    _say(args, f"filled {n_missing - left} samples in {info['seconds']:.2f} s "
               f"({info['n_iter']} iterations); {left} left unfilled -> {out_path}")
    return 0


def _cmd_evaluate(args) -> int:
    import torchfill
    from torchfill import gaps, metrics

    seq = torchfill.read(args.input)
    complete = ~seq.mask.any(axis=0)
    if complete.sum() < 2:
        raise ValueError(f"{args.input}: fewer than 2 markers are complete; "
                         "evaluate needs complete markers to simulate gaps on")
    truth = seq.select(np.flatnonzero(complete))
    T, J = truth.points.shape[:2]
    kwargs = _protocol_kwargs(args, J)
    mask = gaps.generate(args.protocol, T, J, seed=args.seed, **kwargs)
    incomplete = truth.with_points(np.where(mask[..., None], np.nan, truth.points))
    methods = [m for part in args.method for m in part.split(",") if m] or \
        ["linear", "spline", "pchip", torchfill.default_method()]
    _say(args, f"{truth}  (dropped {int((~complete).sum())} incomplete markers)\n"
               f"protocol {args.protocol} {kwargs} seed {args.seed}: "
               f"{int(mask.sum())} missing samples in {int(mask.any(axis=0).sum())} markers")
    rows = []
    for method in dict.fromkeys(methods):
        params = _parse_params(args.param) if len(methods) == 1 else {}
        filled = torchfill.fill(incomplete, method, progress=_progress(args), **params)
        _clear_progress(args)
        info = filled.meta["fill_info"]
        rows.append({"method": method, **metrics.score(filled.points, truth.points, mask),
                     "seconds": info["seconds"], "iterations": info["n_iter"]})
    if args.json:
        print(json.dumps({"file": str(args.input), "protocol": args.protocol, **kwargs,
                          "seed": args.seed, "units": seq.units, "results": rows}, indent=2))
    else:
        print(_table(rows, seq.units))
    return 0


def _cmd_info(args) -> int:
    import torchfill
    from torchfill.metrics import gap_runs

    seq = torchfill.read(args.input, markers_only=not args.all_points)
    runs = gap_runs(seq.mask)
    print(seq)
    print(f"frames {seq.n_frames}, markers {seq.n_markers}, rate {seq.rate:g} Hz, units {seq.units}, "
          f"{len(runs)} gaps, longest {max((b - a for _, a, b in runs), default=0)} frames")
    width = max((len(label) for label in seq.labels), default=6)
    print(f"{'marker':<{width}}  {'missing':>8}  {'gaps':>5}  {'longest':>7}")
    for j, label in enumerate(seq.labels):
        own = [b - a for k, a, b in runs if k == j]
        if own or args.all_markers:
            print(f"{label:<{width}}  {int(seq.mask[:, j].sum()):>8}  {len(own):>5}  "
                  f"{max(own, default=0):>7}")
    return 0


def _cmd_methods(args) -> int:
    from torchfill.solvers import base

    for name in base.available():
        cls = base._REGISTRY[name]
        doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
        print(f"{name:<14} {doc}")
        if args.verbose:
            for key, spec in cls.declared_params().items():
                print(f"    {key} = {spec.default!r}  {spec.doc}")
    return 0


def _cmd_experiment(args) -> int:
    from torchfill.lightning.runner import run_experiment

    out = run_experiment(args.config, resume=args.resume, workers=args.workers,
                         limit=args.limit, output=args.output)
    print(f"results in {out}")
    return 0


# -- helpers ---------------------------------------------------------------------------------------
def _write_std(seq, path: Path) -> None:
    """The error estimate (T, J) as CSV: a frame column, one column per marker, NaN where observed."""
    std = seq.meta["std"]
    table = np.column_stack([np.arange(std.shape[0]), std])
    np.savetxt(path, table, delimiter=",", fmt="%.6g", comments="",
               header=",".join(["frame", *seq.labels]))


def _default_output(path: Path) -> Path:
    return path.with_name(f"{path.stem}_filled{path.suffix}")


def _parse_params(pairs: list[str]) -> dict:
    params = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--param expected NAME=VALUE, found {pair!r}")
        try:
            params[key] = json.loads(value)
        except json.JSONDecodeError:
            params[key] = value
    return params


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
             "rmse_missing over the gaps, gap_error = mean 3-D error per gap", head, "-" * len(head)]
    for row in rows:
        lines.append(f"{row['method']:<12}" + "".join(
            f"{row[c]:>14.4g}" if c != "iterations" else f"{row[c]:>14d}" for c in cols))
    return "\n".join(lines)


def _say(args, text: str) -> None:
    if not getattr(args, "quiet", False):
        print(text, file=sys.stderr if getattr(args, "json", False) else sys.stdout)


def _shows_progress(args) -> bool:
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


def _progress(args):
    if not _shows_progress(args):
        return None
    start = time.perf_counter()

    def show(info: dict) -> None:
        extra = "  ".join(f"{k}={v:.3g}" for k, v in info.items() if k != "iter")
        print(f"\r  iter {int(info['iter']):>5}  {time.perf_counter() - start:6.1f} s  {extra}"[:100],
              end="", file=sys.stderr, flush=True)
    return show


def _clear_progress(args) -> None:
    if _shows_progress(args):
        print("\r" + " " * 100 + "\r", end="", file=sys.stderr, flush=True)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torchfill", description=(
        "Fill gaps in motion-capture marker data (C3D, TRC, .npy/.npz/.csv)."))
    parser.add_argument("--version", action="version", version="torchfill 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("fill", help="fill the gaps of a recording and write the result",
                       description="Fill the gaps of IN and write OUT; everything else in the file "
                                   "is kept, filled C3D samples get residual 0.")
    p.add_argument("input", metavar="IN")
    p.add_argument("-o", "--output", metavar="OUT", help="output file (default: IN_filled.EXT)")
    p.add_argument("-m", "--method", help="method name (see 'torchfill methods'; default: the best)")
    p.add_argument("--max-gap", type=int, metavar="FRAMES", help="leave longer gaps unfilled")
    p.add_argument("--training", nargs="+", metavar="FILE", help="training recordings (pca_*)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a method hyperparameter (repeatable), e.g. -p max_iter=200")
    p.add_argument("--std", metavar="OUT.csv", help="also write the estimated error std per filled "
                   "sample (frames x markers, data units, NaN where observed)")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(run=_cmd_fill)

    p = sub.add_parser("evaluate", help="simulate gaps on complete markers and score methods",
                       description="Simulate gaps on the complete markers of IN, fill them with "
                                   "each method and print the metrics against the truth.")
    p.add_argument("input", metavar="IN")
    p.add_argument("-m", "--method", action="append", default=[],
                   help="method(s), repeatable or comma-separated (default: baselines + the best)")
    p.add_argument("--protocol", default="multi_gap",
                   choices=["multi_gap", "shared_window", "continuous_runs", "evenly_spaced",
                            "blackout", "random_entries"])
    p.add_argument("--markers", type=int, default=20, help="markers with gaps (default 20)")
    p.add_argument("--gap-length", type=int, default=100, help="frames per gap (default 100)")
    p.add_argument("--max-gaps", type=int, default=5, help="gaps per marker, at most (default 5)")
    p.add_argument("--rate", type=float, default=0.2, help="missing rate for random_entries")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="hyperparameter for a single method")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(run=_cmd_evaluate)

    p = sub.add_parser("info", help="frames, markers, and gaps per marker")
    p.add_argument("input", metavar="IN")
    p.add_argument("--all-markers", action="store_true", help="list markers without gaps too")
    p.add_argument("--all-points", action="store_true",
                   help="include model outputs and virtual points (C3D)")
    p.set_defaults(run=_cmd_info)

    p = sub.add_parser("methods", help="list the registered methods")
    p.add_argument("-v", "--verbose", action="store_true", help="show hyperparameters and defaults")
    p.set_defaults(run=_cmd_methods)

    p = sub.add_parser("experiment", help="run an experiment config (YAML) with the Lightning runner")
    p.add_argument("config", metavar="CONFIG")
    p.add_argument("--resume", action="store_true", help="skip cases already finished")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    p.add_argument("--limit", type=int, help="run at most this many cases")
    p.add_argument("--output", help="output folder (default: experiments/results/<name>)")
    p.set_defaults(run=_cmd_experiment)
    return parser


if __name__ == "__main__":
    sys.exit(main())
