"""``torchfill fill`` with several inputs: the whole batch checked, then filled by the process pool."""
from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

from .checks import REPORT_ALSO, _check_format, _check_input, _check_suffix
from .options import _fill_options, _pose_options, _say
from .terminal import EXIT_ERROR


def _cmd_fill_batch(args) -> int:
    """Many files: one progress bar, one line per failing file, a summary table at the end.
    Ctrl-C (or SIGTERM) stops at once: queued files are not started, running ones are stopped
    with nothing partial written, exit status 130."""
    from contextlib import closing

    from tqdm import tqdm

    from torchfill import batch
    from torchfill.io.outputs import Outputs, estimate_path, make_folder

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
    options = _fill_options(args, None)
    _side_check(args.report, "--report")
    if args.std and args.std.lower() == "none":
        args.std = ""                                   # no estimate file, not even beside
    _side_check(args.std or None, "--std")
    out_dir = make_folder(args.out_dir)
    side = {"report": _side_folder(args.report, "--report"),
            "std": _side_folder(args.std or None, "--std")}
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
            if args.std is None and options.method == "auto":   # its estimate comes with it
                std = estimate_path(dst)
            for path, what in ((report, "report"), (std, "--std file")):
                if path is not None:
                    plan.add_output(path, what)
            jobs.append(batch.Job(str(src), str(dst), options, tuple(args.training or ()),
                                  report=report and str(report), std=std and str(std),
                                  read_options=options_of[src],
                                  rejected=args.rejected or "keep"))
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
