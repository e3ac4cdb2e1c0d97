"""Command line: ``torchfill fill | qc | evaluate | info | methods | experiment``
(also ``python -m torchfill``).

Every failure on bad input prints one line, ``torchfill: error: <file>: <problem>``, and exits
with status 2; nothing is written unless the whole fill succeeded.
"""
from __future__ import annotations

import argparse
import ast
from contextlib import contextmanager
import json
import os
import signal
import sys
import time
import warnings
from pathlib import Path

EXIT_ERROR = 2


def main(argv: list[str] | None = None) -> int:
    _install_signal_handlers()
    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return EXIT_ERROR
    try:
        _set_threads(getattr(args, "threads", None))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            status = args.run(args)
        for w in caught:
            if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning)):
                print(f"torchfill: warning: {_one_line(w.message)}", file=sys.stderr)
        return status
    except KeyboardInterrupt:
        print("torchfill: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:                # `torchfill info F | head`: the reader left; be quiet
        _silence_stdout()
        return 141
    except (ValueError, OSError, KeyError) as err:
        print(f"torchfill: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as err:  # a bug, not bad input: still one line unless debugging
        if os.environ.get("TORCHFILL_DEBUG"):
            raise
        print(f"torchfill: internal error: {type(err).__name__}: {_one_line(err)} "
              "(set TORCHFILL_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


def _set_threads(n: int | None) -> None:
    """torch's threads for this run: ``--threads``, else ``OMP_NUM_THREADS``, else the cores the
    machine leaves idle (at least 1). Threads that wait for busy cores are far slower than one:
    a tucker_tnn iteration on 3000 x 41 frames took 84-93 ms with 1 thread and 685-1427 ms with 2
    on this 2-core machine at load 9 (scripts/bench_threads.py)."""
    if n is None:
        if os.environ.get("OMP_NUM_THREADS"):
            return
        cores = os.cpu_count() or 1
        n = max(1, min(cores, int(cores - os.getloadavg()[0] + 0.5)))
    elif n < 1:
        raise ValueError(f"--threads expected >= 1, found {n}")
    os.environ["OMP_NUM_THREADS"] = str(n)       # read when torch is imported (lazily, later)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)


def _install_signal_handlers() -> None:
    """SIGTERM ends the run like Ctrl-C (clean-up runs: no temporary file is left behind)."""
    def on_term(signum, frame):
        raise SystemExit(128 + signum)
    try:
        signal.signal(signal.SIGTERM, on_term)
    except ValueError:                     # not the main thread
        pass


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


# -- sub-commands --------------------------------------------------------------------------------
def _cmd_fill(args) -> int:
    import torchfill

    if len(args.input) > 1 or args.out_dir or args.ray:
        return _cmd_fill_batch(args)
    args.input = args.input[0]
    seq = torchfill.read(args.input, **_pose_options(args))
    out_path = Path(args.output) if args.output else _default_output(Path(args.input))
    torchfill.io.check_target(out_path)                 # refuse now, not after the fill
    params = {"params": _parse_params(args.param)} | _window(args) | _dtype(args)   # -p: the method's
    if args.training:
        params["training"] = [torchfill.read(path) for path in args.training]
    method = torchfill.default_method() if args.method is None else args.method
    n_missing = int(seq.mask.sum())
    want_std = bool(args.std or args.report or args.report_json)   # the qc verdict uses it
    _say(args, f"{seq}\nfilling {n_missing} missing samples with {method} ...")
    with _naming(args.input):
        filled = torchfill.fill(seq, method, max_gap=args.max_gap, progress=_progress(args),
                                constraints=args.constraints, return_std=want_std, **params)
    filled = filled[0] if want_std else filled
    _clear_progress(args)
    torchfill.write(filled, out_path)
    if args.std:
        _write_std(filled, Path(args.std))
    if args.report or args.report_json:
        rows = _qc_rows(seq, filled, filled.meta.get("std"), method)
        if args.report:
            _write_report(seq, filled, Path(args.report), str(args.input), rows,
                          filled.meta.get("std"))
        if args.report_json:
            _write_json(rows, Path(args.report_json))
    info = filled.meta["fill_info"]
    left = int(filled.mask.sum())
    _say(args, f"filled {n_missing - left} samples in {info['seconds']:.2f} s "
               f"({info['n_iter']} iterations); {left} left unfilled -> {out_path}")
    return 0


def _cmd_qc(args) -> int:
    import torchfill
    from torchfill import qc

    seq = torchfill.read(args.input, **_pose_options(args))
    filled = _read_filled(args.filled, args)
    if filled.points.shape != seq.points.shape:
        raise ValueError(f"{args.filled}: shape {filled.points.shape} differs from "
                         f"{args.input}'s {seq.points.shape}")
    std = _read_std(Path(args.std), seq) if args.std else filled.meta.get("std")
    rows = _qc_rows(seq, filled, std, args.method or torchfill.default_method())
    if args.json == "-":
        print(json.dumps(qc.to_json(rows), indent=1))
    else:
        print(qc.format_table(rows, seq.units))
    report = Path(args.output) if args.output else Path(args.filled).with_suffix(".qc.html")
    _write_report(seq, filled, report, str(args.filled), rows, std)
    if args.json and args.json != "-":
        _write_json(rows, Path(args.json))
    if not args.quiet:
        print(f"{qc.summary(rows)} -> {report}", file=sys.stderr if args.json == "-" else sys.stdout)
    return 0


def _frame0(seq) -> int:
    """The file's number of the first frame (C3D first frame, TRC Frame#; 0 for arrays)."""
    value = getattr(seq, "first_frame", None)
    if value is None:
        value = seq.meta.get("first_frame", 0)
    return int(value or 0)


def _read_filled(path, args):
    """A filled recording; an OpenPose folder's filled keypoints are read as points (also those
    of folders filled before they were marked: confidence 0, coordinates written)."""
    import torchfill

    if Path(path).is_dir():
        return torchfill.read(path, include_filled=True, **_pose_options(args))
    return torchfill.read(path)


def _read_std(path: Path, seq):
    """The ``fill --std`` CSV (a frame column, one column per marker) as (T, J), by label."""
    import numpy as np

    try:
        with open(path, encoding="utf-8") as f:
            head = f.readline().rstrip("\n").split(",")
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as err:
        raise ValueError(f"{path}: not a std CSV written by 'fill --std' ({_one_line(err)})") \
            from None
    if table.shape[0] != seq.n_frames or table.shape[1] != len(head):
        raise ValueError(f"{path}: {table.shape[0]} rows x {table.shape[1]} columns, expected "
                         f"{seq.n_frames} frames and a column per marker")
    column = {label: i for i, label in enumerate(head[1:], start=1)}
    missing = [label for label in seq.labels if label not in column]
    if missing:
        raise ValueError(f"{path}: no column for marker(s) {', '.join(missing[:5])}")
    return table[:, [column[label] for label in seq.labels]]


def _qc_rows(seq, filled, std, method: str | None = None):
    """The qc rows; ``method`` made the fill (a spatial one's trial-end fills in frames with
    enough markers seen are not extrapolations in time)."""
    from torchfill import qc
    from torchfill.solvers import base

    spatial = bool(getattr(base._REGISTRY.get(method or ""), "spatial", False))
    return qc.gap_table(seq.points, filled.points, seq.rate, seq.labels, std,
                        units=seq.units, first_frame=_frame0(seq),
                        support=filled.meta.get("support"), spatial=spatial)


def _write_report(seq, filled, path: Path, title: str, rows=None, std=None) -> None:
    from torchfill import qc

    rows = rows if rows is not None else _qc_rows(seq, filled, std)
    path.write_text(qc.html_report(seq.points, filled.points, rows, title=title, rate=seq.rate,
                                   units=seq.units, names=seq.labels, std=std,
                                   first_frame=_frame0(seq)), encoding="utf-8")


def _write_json(rows, path: Path) -> None:
    from torchfill import qc

    path.write_text(json.dumps(qc.to_json(rows), indent=1) + "\n", encoding="utf-8")


def _cmd_fill_batch(args) -> int:
    """Many files: one progress bar, one line per failing file, a summary table at the end."""
    from tqdm import tqdm

    from torchfill import batch

    if args.output:
        raise ValueError("-o/--output names one file; give --out-dir DIR for several inputs")
    if not args.out_dir:
        raise ValueError("several inputs need --out-dir DIR")
    if args.workers < 1:
        raise ValueError(f"--workers expected >= 1, found {args.workers}")
    inputs = batch.expand(args.input)
    if not inputs:
        raise ValueError(f"{' '.join(args.input)}: no recordings found")
    params = {"params": _parse_params(args.param)} | _window(args) | _dtype(args)   # -p: the method's
    if not args.constraints:
        params["constraints"] = False
    jobs = [batch.Job(str(src), str(dst), args.method, params, args.max_gap, tuple(args.training or ()))
            for src, dst in zip(inputs, batch.outputs(inputs, Path(args.out_dir)))]
    order = {job.input: i for i, job in enumerate(jobs)}
    rows = []
    with tqdm(total=len(jobs), unit="file", file=sys.stderr, disable=args.quiet or None) as bar:
        for row in batch.run(jobs, workers=args.workers, ray_address=args.ray):
            if row["error"]:
                bar.write(f"torchfill: error: {row['error']}", file=sys.stderr)
            rows.append(row)
            bar.update()
    rows.sort(key=lambda row: order[row["file"]])
    _say(args, batch.table(rows))
    return EXIT_ERROR if any(row["error"] for row in rows) else 0


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
        _clear_progress(args)
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


def _cmd_info(args) -> int:
    import torchfill
    from torchfill.metrics import gap_runs

    seq = torchfill.read(args.input, markers_only=not args.all_points, **_pose_options(args))
    T = seq.n_frames
    never = seq.mask.all(axis=0)
    runs = [(j, a, b) for j, a, b in gap_runs(seq.mask) if not never[j]]   # gaps of seen markers
    inner = [b - a for _, a, b in runs if a > 0 and b < T]
    seen = seq.mask[:, ~never]
    print(seq)
    f0 = _frame0(seq)
    print(f"frames {T} (numbered {f0}-{f0 + T - 1} as in the file), markers {seq.n_markers}, "
          f"rate {seq.rate:g} Hz, units {seq.units}, "
          f"{len(runs)} gaps, longest {max((b - a for _, a, b in runs), default=0)} frames")
    print(f"  {len(inner)} interior gap(s) (longest {max(inner, default=0)} frames), "
          f"{len(runs) - len(inner)} at the trial ends; "
          f"{100.0 * seen.mean() if seen.size else 0.0:.1f}% missing in observed markers; "
          f"{int(seq.mask.all(axis=1).sum())} frame(s) with no marker seen")
    if never.any():
        print(f"  {int(never.sum())} marker(s) never observed: "
              f"{', '.join(seq.labels[j] for j in range(seq.n_markers) if never[j])}")
    dups = seq.duplicates()
    if dups:
        print("  duplicate labels: " + ", ".join(f"{label} (markers {', '.join(map(str, idx))})"
                                                 for label, idx in dups.items()))
    width = max((len(label) for label in seq.labels), default=6)
    print(f"{'marker':<{width}}  {'missing':>8}  {'gaps':>5}  {'longest':>7}  frames (file's numbering)")
    for j, label in enumerate(seq.labels):
        spans = [(a, b) for k, a, b in runs if k == j]
        own = [b - a for a, b in spans]
        if own or never[j] or args.all_markers:
            where = ", ".join(f"{f0 + a}-{f0 + b - 1}" for a, b in spans[:4]) + \
                (f", ... ({len(spans)} gaps)" if len(spans) > 4 else "")
            print(f"{label:<{width}}  {int(seq.mask[:, j].sum()):>8}  {len(own):>5}  "
                  f"{max(own, default=0):>7}  " + ("never observed" if never[j] else where))
    return 0


def _cmd_methods(args) -> int:
    if not args.verbose:  # names and summaries read from the sources: no torch import
        from torchfill._catalog import entries

        for name, doc in entries():
            print(f"{name:<14} {doc}")
        return 0
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
    try:
        from torchfill.lightning.runner import run_experiment
    except ImportError as err:            # the optional [experiments] extra is not installed
        if "torchfill[experiments]" not in str(err):
            raise
        raise ValueError(str(err)) from None

    out = run_experiment(args.config, resume=args.resume, workers=args.workers,
                         limit=args.limit, output=args.output, report_only=args.report_only,
                         ray_address=args.ray)
    print(f"results in {out}")
    return 0


# -- helpers ---------------------------------------------------------------------------------------
@contextmanager
def _naming(path):
    """Errors about the input (too few frames, unknown method or hyperparameter...) name it."""
    try:
        yield
    except ValueError as err:
        if str(path) in str(err):
            raise
        raise ValueError(f"{path}: {_one_line(err)}") from None


def _write_std(seq, path: Path) -> None:
    """The error estimate (T, J) as CSV: a frame column, one column per marker, NaN where observed."""
    import numpy as np

    std = seq.meta["std"]
    table = np.column_stack([_frame0(seq) + np.arange(std.shape[0]), std])
    np.savetxt(path, table, delimiter=",", fmt="%.6g", comments="",
               header=",".join(["frame", *seq.labels]))


def _default_output(path: Path) -> Path:
    return path.with_name(f"{path.stem}_filled{path.suffix}")


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


def _pose_options(args) -> dict:
    """Reader options of OpenPose folders (``--min-confidence``); an error for other inputs."""
    value = getattr(args, "min_confidence", None)
    if value is None:
        return {}
    if not Path(args.input).is_dir():
        raise ValueError(f"{args.input}: --min-confidence applies to OpenPose folders only")
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
        "Fill gaps in motion-capture marker data (C3D, TRC, .npy/.npz/.csv) and 2-D keypoint "
        "tracks (OpenPose output folders)."))
    parser.add_argument("--version", action="version", version="torchfill 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("fill", help="fill the gaps of a recording and write the result",
                       description="Fill the gaps of IN and write OUT; everything else in the file "
                                   "is kept, filled C3D samples get residual 0.")
    p.add_argument("input", metavar="IN", nargs="+",
                   help="recording(s): files, folders or glob patterns (several need --out-dir)")
    p.add_argument("-o", "--output", metavar="OUT", help="output file (default: IN_filled.EXT)")
    p.add_argument("--out-dir", metavar="DIR", help="write each filled recording here, same name")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="fill N files at once in separate processes (default 1)")
    p.add_argument("--ray", metavar="ADDRESS", help="distribute the files as Ray tasks: 'auto' "
                   "(a running cluster), 'local' (start one here) or ray://HOST:PORT")
    p.add_argument("-m", "--method", help="method name (see 'torchfill methods'; default: the best)")
    p.add_argument("--max-gap", type=int, metavar="FRAMES", help="leave longer gaps unfilled")
    p.add_argument("--window", type=int, metavar="FRAMES",
                   help="fill longer recordings in overlapping windows of this many frames "
                        "(default 6000; 0: the whole recording at once)")
    p.add_argument("--training", nargs="+", metavar="FILE", help="training recordings (pca_*)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a method hyperparameter (repeatable), e.g. -p max_iter=200; "
                        "values as 'methods -v' shows them (True, None, (8, 8, 3)) or JSON")
    p.add_argument("--report", metavar="REPORT.html", help="also write the qc report of the fill")
    p.add_argument("--report-json", metavar="REPORT.json",
                   help="also write the qc verdicts as JSON (one object per gap)")
    p.add_argument("--no-constraints", dest="constraints", action="store_false",
                   help="the method's own fill, as in its paper (no rigid donors, edge blending, "
                        "step limit, volume clamp or extrapolation limit)")
    p.add_argument("--dtype", choices=("float32", "float64"),
                   help="what the method computes in (default: its own, float32 for tucker and "
                        "tucker_tnn); observed samples are written as read either way")
    p.add_argument("--std", metavar="OUT.csv", help="also write the estimated error std per filled "
                   "sample (frames x markers, data units, NaN where observed)")
    p.add_argument("-q", "--quiet", action="store_true")
    _add_threads(p)
    _add_pose_options(p)
    p.set_defaults(run=_cmd_fill)

    p = sub.add_parser("qc", help="which filled gaps to trust: a per-gap report (text + HTML)",
                       description="Judge the fill FILLED of IN gap by gap (interpolated or "
                                   "extrapolated, rigid donors, rigid deviation, edge jump, "
                                   "largest step, outside the volume) and write an HTML report.")
    p.add_argument("input", metavar="IN")
    p.add_argument("filled", metavar="FILLED")
    p.add_argument("-o", "--output", metavar="REPORT.html",
                   help="HTML report (default: FILLED with suffix .qc.html)")
    p.add_argument("--json", metavar="OUT.json", help="also write the verdicts as JSON, one object "
                   "per gap: marker, first_frame, last_frame (the file's numbering), verdict, "
                   "est_rmse (file units), reasons, segment ('-': print it instead of the table)")
    p.add_argument("--std", metavar="STD.csv",
                   help="the fill's error estimate ('fill --std' output): verdicts use it")
    p.add_argument("-m", "--method", help="the method that made FILLED (default: the default "
                   "method); a spatial method's trial-end fills in frames with enough markers "
                   "seen do not count as extrapolated in time")
    p.add_argument("-q", "--quiet", action="store_true")
    _add_pose_options(p)
    p.set_defaults(run=_cmd_qc)

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
    _add_threads(p)
    _add_pose_options(p)
    p.set_defaults(run=_cmd_evaluate)

    p = sub.add_parser("info", help="frames, markers, and gaps per marker")
    p.add_argument("input", metavar="IN")
    p.add_argument("--all-markers", action="store_true", help="list markers without gaps too")
    p.add_argument("--all-points", action="store_true",
                   help="include model outputs and virtual points (C3D)")
    _add_pose_options(p)
    p.set_defaults(run=_cmd_info)

    p = sub.add_parser("methods", help="list the registered methods")
    p.add_argument("-v", "--verbose", action="store_true", help="show hyperparameters and defaults")
    p.set_defaults(run=_cmd_methods)

    p = sub.add_parser("experiment", help="run an experiment config (YAML) with the Lightning runner")
    p.add_argument("config", metavar="CONFIG")
    p.add_argument("--resume", action="store_true", help="skip cases already finished")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    p.add_argument("--limit", type=int, help="run at most this many cases")
    p.add_argument("--output", help="output folder (default: results/<name> beside the config)")
    p.add_argument("--report-only", action="store_true",
                   help="only rewrite table.md and the plots from the cases.csv there")
    p.add_argument("--ray", metavar="ADDRESS", help="run the cases as Ray tasks: 'auto', 'local' "
                   "or ray://HOST:PORT (every node needs the recordings at the same path)")
    p.set_defaults(run=_cmd_experiment)
    return parser


def _add_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=int, metavar="N",
                   help="torch threads (default: OMP_NUM_THREADS, else the idle cores, at least 1)")


def _add_pose_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--min-confidence", type=float, metavar="C",
                   help="OpenPose folder: keypoints with confidence below C are missing "
                        "(default: only confidence 0)")


if __name__ == "__main__":
    sys.exit(main())
