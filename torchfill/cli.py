"""Command line: ``torchfill fill | qc | evaluate | info | methods | experiment``
(also ``python -m torchfill``).

Every failure on bad input prints one line, ``torchfill: error: <file>: <problem>``, and exits
with status 2; nothing is written unless the whole fill succeeded.
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
from contextlib import contextmanager
import json
import os
import re
import signal
import sys
import time
import warnings
from pathlib import Path

EXIT_ERROR = 2


def main(argv: list[str] | None = None) -> int:
    _install_signal_handlers()
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _Escaping(sys.stdout), _Escaping(sys.stderr)
    try:
        return _main(argv)
    finally:
        sys.stdout, sys.stderr = saved


def _main(argv: list[str] | None) -> int:
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
        for w in caught if getattr(args, "quiet", 0) < 2 else ():      # -qq: errors only
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


#: characters that can move the cursor, retitle, clear or recolour a terminal, or reorder text:
#: C0 and C1 controls but tab and newline, DEL, bidirectional overrides and isolates
_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def escape(text: str) -> str:
    """``text`` with terminal control characters shown as escapes (``\\x1b``): labels, units and
    file names come from files and must not drive the terminal that prints them."""
    return _CONTROL.sub(lambda m: (f"\\x{ord(m[0]):02x}" if ord(m[0]) < 256
                                   else f"\\u{ord(m[0]):04x}"), text)


def _shown(text: str) -> str:
    """One field of a table as printed: control characters and line breaks escaped."""
    return escape(str(text)).replace("\n", "\\n").replace("\t", "\\t")


class _Escaping:
    """A text stream that escapes control characters in what it is given (:func:`escape`); a
    carriage return at the start or end of one write stays (progress lines rewrite themselves)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        body = text.strip("\r")
        if body != text:
            head = text[:len(text) - len(text.lstrip("\r"))]
            tail = text[len(text.rstrip("\r")):] if body else ""
            text = head + escape(body) + tail
        else:
            text = escape(text)
        return self._stream.write(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


# -- sub-commands --------------------------------------------------------------------------------
def _cmd_fill(args) -> int:
    import torchfill

    if args.training:                                 # folders as the recordings they hold
        from torchfill.batch import expand
        args.training = [str(path) for path in expand(args.training)]
        if not args.training:
            raise ValueError("--training: no recordings found")
    if args.session and not (len(args.input) > 1 or args.out_dir):
        raise ValueError("--session fills a batch: give several inputs and --out-dir DIR")
    if len(args.input) > 1 or args.out_dir or args.ray:
        return _cmd_fill_batch(args)
    src = Path(args.input[0])
    plan, out_path, backup = _plan_fill(args, src)     # every check before any file is read
    with plan:
        method, options = _fill_options(args, src)
        plan.keep_templates()
        seq = torchfill.read(src, **_pose_options(args))
        if args.training:
            options["training"] = [torchfill.read(path) for path in args.training]
        plan.confirm_inputs()
        n_missing = int(seq.mask.sum())
        _say(args, f"{seq}\nfilling {n_missing} missing samples with {method} ...")
        want_std = bool(args.std or args.report or args.report_json)   # the qc verdict uses it
        with _naming(src):
            filled = torchfill.fill(seq, method, max_gap=args.max_gap, progress=_progress(args),
                                    return_std=want_std, **options)
        filled = filled[0] if want_std else filled
        plan.write_sequence(filled, out_path, backup=backup)
        written = [out_path]
        if args.std:
            _write_std(filled, Path(args.std), plan)
            written.append(args.std)
        if args.report or args.report_json:
            rows = _qc_rows(seq, filled, filled.meta.get("std"), method)
            if args.report:
                _write_report(seq, filled, Path(args.report), str(src), rows, plan=plan)
                written.append(args.report)
            if args.report_json:
                _write_json(rows, Path(args.report_json), plan)
                written.append(args.report_json)
    info = filled.meta["fill_info"]
    left = int(filled.mask.sum())
    steps = f" ({info['n_iter']} iterations)" if info["n_iter"] > info["windows"] else ""
    _say(args, f"filled {n_missing - left} samples in {info['seconds']:.2f} s{steps}; "
               f"{left} left unfilled -> "
               + ", ".join(map(str, written))
               + (f" (original kept as {backup})" if backup else ""))
    return 0


def _plan_fill(args, src: Path):
    """The guarded writer of a single-file fill with every path checked (see io/outputs.py), the
    output path and the backup path of ``--in-place`` (or None)."""
    from torchfill.io.outputs import Outputs

    _check_input(src, batch_hint=True)
    plan = Outputs()
    try:
        return (plan, *_plan_paths(args, src, plan))
    except BaseException:
        plan.close()
        raise


def _plan_paths(args, src: Path, plan) -> tuple[Path, Path | None]:
    from torchfill.io import FileFormatError

    openpose = src.is_dir()
    plan.add_input(src, template=True)
    for path in args.training or ():
        _check_input(Path(path))
        plan.add_input(path, "training")
    backup = None
    if args.in_place:
        if args.output:
            raise FileFormatError(f"{src}: --in-place writes onto the input; leave out -o")
        if openpose:
            raise FileFormatError(f"{src}: --in-place writes files, not OpenPose folders; give -o")
        out = src
        if not args.no_backup:
            backup = src.with_name(f"{src.stem}.orig{src.suffix}")
            if os.path.lexists(backup):
                raise FileFormatError(f"{backup}: exists (an earlier original?); move it "
                                      "away, or give --no-backup")
    else:
        if args.no_backup:
            raise FileFormatError(f"{src}: --no-backup goes with --in-place")
        out = Path(args.output) if args.output else _default_output(src)
        if args.output and not openpose and (args.output.endswith(("/", os.sep)) or out.is_dir()):
            raise FileFormatError(f"{out}: is a folder; give a file name (e.g. "
                                  f"{out / _default_output(src).name}), or --out-dir {out} to "
                                  "fill several recordings")
    _check_format(out, openpose)
    plan.add_output(out, "output", replace_input=args.in_place, folder=openpose,
                                    hint="give another -o, or --in-place to replace it (the "
                                         "original is kept as NAME.orig.EXT)")
    if backup is not None:
        plan.add_output(backup, "backup")
    if args.std:
        _check_suffix(Path(args.std), ".csv", "--std")
        plan.add_output(args.std, "--std file")
    if args.report:
        _check_suffix(Path(args.report), ".html", "--report", REPORT_ALSO)
        plan.add_output(args.report, "report")
    if getattr(args, "report_json", None):
        _check_suffix(Path(args.report_json), ".json", "--report-json")
        plan.add_output(args.report_json, "--report-json file")
    return out, backup


def _check_input(path: Path, batch_hint: bool = False) -> None:
    """One line now if ``path`` cannot be read as a recording: missing, of an unknown type, or a
    folder of recordings (not an OpenPose folder) without ``--out-dir``."""
    from torchfill.io import FileFormatError, _pick

    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    if path.is_dir():
        from torchfill.batch import SUFFIXES
        from torchfill.io.openpose import PATTERN

        if not any(path.glob(PATTERN)):
            found = [p for p in path.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES]
            if found and batch_hint:
                raise FileFormatError(f"{path}: a folder of {len(found)} recording(s), not an "
                                      f"OpenPose folder; fill them all with --out-dir DIR")
            raise FileFormatError(f"{path}: a folder with no recordings and no OpenPose "
                                  f"{PATTERN} files")
        return
    _pick(path, "read")


def _check_format(out: Path, openpose: bool) -> None:
    """The output's type from its suffix, now (a folder without suffix: OpenPose output)."""
    from torchfill.io import FileFormatError, _pick

    if not out.suffix and not openpose:
        raise FileFormatError(f"{out}: no file type; give a suffix (.c3d, .trc, .npy, .npz, "
                              ".csv)")
    _pick(out, "write")


#: The hint after a ``--report`` name of another format.
REPORT_ALSO = " (the per-gap verdicts as JSON: --report-json FILE.json)"


def _check_suffix(path: Path, suffix: str, option: str, also: str = "") -> None:
    """One line now if ``path`` does not end in ``suffix`` (or ``.htm`` for ``.html``): the file
    would hold another format than its name says (``also``: what to use instead)."""
    if path.suffix.lower() != suffix and (suffix, path.suffix.lower()) != (".html", ".htm"):
        raise ValueError(f"{path}: {option} writes {suffix}, found "
                         f"{path.suffix or 'no suffix'}{also}")


def _fill_options(args, src) -> tuple[str, dict]:
    """The method and ``fill()`` keywords of the command line, checked before any file is read:
    method name and ``-p`` names with a "did you mean", values by the method's own checks."""
    import difflib

    from torchfill._catalog import entries, mentioned

    src = f"{src}: " if src is not None else ""
    if args.max_gap is not None and args.max_gap < 0:
        raise ValueError(f"{src}max_gap expected >= 0, found {args.max_gap}")
    params = _parse_params(args.param)
    _extrapolate(args)
    if args.method is not None and not mentioned(args.method):     # a typo: say so before torch
        names = [name for name, _ in entries()]        # read from the sources: no torch yet
        if args.method not in names:
            raise _unknown_method(src, args.method, names)
    import torchfill
    from torchfill.solvers import base

    names = torchfill.methods()
    method = torchfill.default_method() if args.method is None else args.method
    if method not in names:
        raise _unknown_method(src, method, names)
    cls = base._REGISTRY[method]
    declared = [*cls.declared_params(), *cls._merged("renamed")]
    for key in params:
        if key in _FILL_OPTIONS and key not in declared:     # pma's own window is -p window=
            raise ValueError(f"{src}-p {key}: a fill option, give it as --{key.replace('_', '-')}")
        if key not in declared:
            close = difflib.get_close_matches(key, declared, n=1)
            raise ValueError(f"{src}{method} has no hyperparameter {key!r}"
                             + (f"; did you mean {close[0]!r}?" if close else "")
                             + " ('torchfill methods -v' lists them)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            base.get_solver(method, **params)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{src}{_one_line(err)}") from None
    if (args.training or getattr(args, "session", False)) and "training" not in cls.fit_data:
        takes = [m for m in names if "training" in base._REGISTRY[m].fit_data]
        raise ValueError(f"{src}{method} takes no training data; methods that do: "
                         f"{', '.join(takes)}")
    options = ({"params": params} | _window(args) | _dtype(args) | _extrapolate(args)
               | _segments(args))
    options["constraints"] = args.constraints
    return method, options


def _unknown_method(src: str, method: str, names: list[str]) -> ValueError:
    import difflib

    close = difflib.get_close_matches(method, names, n=1)
    return ValueError(f"{src}unknown method {method!r}"
                      + (f"; did you mean {close[0]!r}?" if close else "")
                      + " ('torchfill methods' lists them)")


#: ``fill()`` keywords that have their own command-line option
_FILL_OPTIONS = ("mask", "max_gap", "window", "constraints", "extrapolate", "return_std", "dtype",
                 "workers", "progress", "training")


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


def _cmd_qc(args) -> int:
    import torchfill
    from torchfill import qc
    from torchfill.io.outputs import Outputs

    report = Path(args.output) if args.output else Path(args.filled).with_suffix(".qc.html")
    _check_suffix(report, ".html", "qc -o", " (the verdicts as JSON: --json FILE.json)")
    to_file = args.json and args.json != "-"
    if to_file:
        _check_suffix(Path(args.json), ".json", "--json")
    with Outputs() as plan:
        for path in (args.input, args.filled):
            _check_input(Path(path))
            plan.add_input(path)
        if args.std:
            plan.add_input(args.std)
        plan.add_output(report, "qc report", hint="give another -o")
        if to_file:
            plan.add_output(args.json, "--json file")
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
        _write_report(seq, filled, report, str(args.filled), rows, std, plan=plan)
        if to_file:
            _write_json(rows, Path(args.json), plan)
    if not args.quiet:
        print(f"{qc.summary(rows)} -> {report}", file=sys.stderr if args.json == "-" else sys.stdout)
    return 0


def _frame0(seq) -> int:
    """The file's number of the first frame (C3D first frame, TRC Frame#; 0 for arrays)."""
    return int(getattr(seq, "first_frame", 0) or 0)


def _read_filled(path, args):
    """A filled recording; an OpenPose folder's filled keypoints are read as points (also those
    of folders filled before they were marked: confidence 0, coordinates written)."""
    import torchfill

    if Path(path).is_dir():
        return torchfill.read(path, include_filled=True, **_pose_options(args, Path(path)))
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
    from torchfill import batch

    return batch.qc_rows(seq, filled, std, method)


def _write_report(seq, filled, path: Path, title: str, rows=None, std=None, plan=None) -> None:
    from torchfill import batch

    batch.write_report(seq, filled, path, title, rows, plan, std=std)


def _write_json(rows, path: Path, plan) -> None:
    from torchfill import qc

    plan.write_text(path, json.dumps(qc.to_json(rows), indent=1) + "\n", "qc JSON")


def _cmd_fill_batch(args) -> int:
    """Many files: one progress bar, one line per failing file, a summary table at the end.
    Ctrl-C (or SIGTERM) stops at once: queued files are not started, running ones are stopped
    with nothing partial written, exit status 130."""
    from contextlib import closing

    from tqdm import tqdm

    from torchfill import batch
    from torchfill.io.outputs import Outputs, make_folder

    if args.output:
        raise ValueError("-o/--output names one file; give --out-dir DIR for several inputs")
    if not args.out_dir:
        raise ValueError("several inputs need --out-dir DIR")
    if args.in_place or args.no_backup:
        raise ValueError("--in-place fills one file; give --out-dir DIR for several inputs")
    if args.workers < 1:
        raise ValueError(f"--workers expected >= 1, found {args.workers}")
    inputs = batch.expand(args.input)
    if not inputs:
        raise ValueError(f"{' '.join(args.input)}: no recordings found")
    method, options = _fill_options(args, None)
    _side_check(args.report, "--report")
    _side_check(args.std, "--std")
    out_dir = make_folder(args.out_dir)
    side = {"report": _side_folder(args.report, "--report"), "std": _side_folder(args.std, "--std")}
    options_of = {src: _pose_options(args, src) for src in inputs}
    jobs = []
    with Outputs() as plan:                           # the whole batch checked before any work
        for path in args.training or ():
            _check_input(Path(path))
            plan.add_input(path, "training")
        for src in inputs:
            plan.add_input(src)
        for src, dst in zip(inputs, batch.outputs(inputs, out_dir)):
            if not src.is_dir():
                _check_format(dst, False)
            plan.add_output(dst, "output", folder=src.is_dir(), hint="choose another --out-dir")
            report, std = (batch.side_name(side[k], src, k) if side[k] else None
                           for k in ("report", "std"))
            for path, what in ((report, "report"), (std, "--std file")):
                if path is not None:
                    plan.add_output(path, what)
            jobs.append(batch.Job(str(src), str(dst), method, options, args.max_gap,
                                  tuple(args.training or ()), report=report and str(report),
                                  std=std and str(std), read_options=options_of[src]))
    if args.session:        # the batch's other files of each marker set as training, read once
        pool = batch.session(inputs, [options_of[src] for src in inputs])
        jobs = [dataclasses.replace(job, session=pool.get(src, ())) for job, src in zip(jobs, inputs)]
    order = {job.input: i for i, job in enumerate(jobs)}
    rows = []
    started = time.time()
    try:
        with tqdm(total=len(jobs), unit="file", file=sys.stderr,
                  disable=bool(args.quiet) or None) as bar, \
                closing(batch.run(jobs, workers=args.workers, ray_address=args.ray)) as results:
            for row in results:
                if row["error"]:
                    bar.write(f"torchfill: error: {row['error']}", file=sys.stderr)
                rows.append(row)
                bar.update()
    except (KeyboardInterrupt, SystemExit) as stop:     # the workers are gone by now
        done = sum(1 for job in jobs if _written_since(job.output, started))
        failed = sum(1 for row in rows if row["error"])
        print(f"torchfill: interrupted: {done} of {len(jobs)} file(s) filled, {failed} failed, "
              f"{len(jobs) - done - failed} stopped or not started (nothing partial written)",
              file=sys.stderr)
        return 130 if isinstance(stop, KeyboardInterrupt) else (stop.code or 130)
    rows.sort(key=lambda row: order[row["file"]])
    _say(args, batch.table(rows))
    return EXIT_ERROR if any(row["error"] for row in rows) else 0


def _written_since(path: str, start: float) -> bool:
    try:
        return os.stat(path).st_mtime >= start - 1.0
    except OSError:
        return False


def _side_folder(value: str | None, option: str) -> str | None:
    """``--report`` / ``--std`` in a batch: a folder (created) or a name with ``{stem}``."""
    from torchfill.io.outputs import make_folder

    if value is None:
        return None
    if _side_check(value, option):
        make_folder(Path(value).parent if str(Path(value).parent) else Path("."))
        return value
    make_folder(value)
    return str(Path(value)) + os.sep


def _side_check(value: str | None, option: str) -> bool:
    """One line now, before any folder is made, unless ``value`` is a folder or a name with
    ``{stem}`` ending in the option's suffix; whether it is such a name."""
    if value is None:
        return False
    if "{stem}" in value or "{name}" in value:
        _check_suffix(Path(value), ".html" if option == "--report" else ".csv", option,
                      REPORT_ALSO if option == "--report" else "")
        return True
    if value.endswith(("/", os.sep)) or Path(value).is_dir() or not Path(value).suffix:
        return False
    raise ValueError(f"{value}: with several inputs {option} takes a folder or a name with "
                     "{stem} (e.g. reports/{stem}.qc.html)")


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


def _cmd_info(args) -> int:
    import torchfill
    from torchfill.metrics import gap_runs

    seq = torchfill.read(args.input, markers_only=not args.all_points, **_pose_options(args))
    if args.segments is not None:          # the segments a fill would use, as an editable YAML
        from torchfill.segments import resolve
        source = None if args.segments == "auto" else args.segments
        segs = resolve(source, seq.labels, seq.points, ~seq.mask)
        sys.stdout.write(segs.to_yaml())
        return 0
    T = seq.n_frames
    never = seq.mask.all(axis=0)
    runs = [(j, a, b) for j, a, b in gap_runs(seq.mask) if not never[j]]   # gaps of seen markers
    inner = [b - a for _, a, b in runs if a > 0 and b < T]
    seen = seq.mask[:, ~never]
    labels = [_shown(label) for label in seq.labels]     # a newline in a label stays visible too
    print(seq)
    f0 = _frame0(seq)
    print(f"frames {T} (numbered {f0}-{f0 + T - 1} as in the file), markers {seq.n_markers}, "
          f"rate {seq.rate:g} Hz, units {_shown(seq.units)}, "
          f"{len(runs)} gaps, longest {max((b - a for _, a, b in runs), default=0)} frames")
    print(f"  {len(inner)} interior gap(s) (longest {max(inner, default=0)} frames), "
          f"{len(runs) - len(inner)} at the trial ends; "
          f"{100.0 * seen.mean() if seen.size else 0.0:.1f}% missing in observed markers; "
          f"{int(seq.mask.all(axis=1).sum())} frame(s) with no marker seen")
    if never.any():
        print(f"  {int(never.sum())} marker(s) never observed: "
              f"{', '.join(labels[j] for j in range(seq.n_markers) if never[j])}")
    dups = seq.duplicates()
    if dups:
        print("  duplicate labels: " + ", ".join(f"{_shown(label)} "
                                                 f"(markers {', '.join(map(str, idx))})"
                                                 for label, idx in dups.items()))
    width = max((len(label) for label in labels), default=6)
    print(f"{'marker':<{width}}  {'missing':>8}  {'gaps':>5}  {'longest':>7}  "
          "frames (file's numbering)")
    for j, label in enumerate(labels):
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


def _write_std(seq, path: Path, plan) -> None:
    """The error estimate (T, J) as CSV: a frame column, one column per marker, NaN where observed."""
    from torchfill import batch

    plan.write_text(path, batch.std_csv(seq), "--std file")


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


def _progress(args) -> bool:
    """A fill's bar (percent, time left; see torchfill.progress) on a terminal, unless -q. Not
    on a terminal the command's own summary line is the only report."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


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
    p.add_argument("--training", nargs="+", metavar="FILE",
                   help="training recordings (files or folders): other trials of the same marker "
                        "set whose observed samples the spatial models and the default learn from "
                        "(methods with training data: 'torchfill methods -v')")
    p.add_argument("--session", action="store_true",
                   help="with several inputs: every input is training for the others of its "
                        "marker set (their observed samples only; read once, one pool per "
                        "marker set)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a method hyperparameter (repeatable), e.g. -p max_iter=200; "
                        "values as 'methods -v' shows them (True, None, (8, 8, 3)) or JSON")
    p.add_argument("--report", metavar="REPORT.html", help="also write the qc report of the fill "
                   "(several inputs: a folder, or a name with {stem})")
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
    p.add_argument("--extrapolate", metavar="SECONDS",
                   help="seconds a gap at a trial end may be extrapolated in time, in frames "
                        "too empty for a spatial fill (default 0.25); with a limit, markers never "
                        "seen in two consecutive frames, and uncertain fills of a marker whose "
                        "segment-mates are never observed, are left NaN too; 'none': no limit, "
                        "every sample filled")
    p.add_argument("--in-place", action="store_true",
                   help="write the fill onto IN itself (keeps the original as NAME.orig.EXT unless "
                        "--no-backup)")
    p.add_argument("--no-backup", action="store_true", help="with --in-place: keep no .orig copy")
    p.add_argument("--segments", metavar="FILE",
                   help="which markers move together: a YAML file as 'torchfill info IN "
                        "--segments' prints, 'names' (marker-set tables) or 'data' (found in the "
                        "recording); default: the tables when the labels fit, else the data")
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress and no summary: only warnings and errors (-qq: only errors)")
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
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress and no summary: only warnings and errors (-qq: only errors)")
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
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress and no summary: only warnings and errors (-qq: only errors)")
    _add_threads(p)
    _add_pose_options(p)
    p.set_defaults(run=_cmd_evaluate)

    p = sub.add_parser("info", help="frames, markers, and gaps per marker")
    p.add_argument("input", metavar="IN")
    p.add_argument("--all-markers", action="store_true", help="list markers without gaps too")
    p.add_argument("--all-points", action="store_true",
                   help="include model outputs and virtual points (C3D)")
    p.add_argument("--segments", nargs="?", const="auto", metavar="SOURCE",
                   help="print the segments a fill uses (YAML to edit and pass back with fill "
                        "--segments FILE); SOURCE: 'names', 'data', a YAML file or the default")
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
