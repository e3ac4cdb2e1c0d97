"""``torchfill fill IN``: one recording, every output path checked before any work."""
from __future__ import annotations

import os
from pathlib import Path

from .batch import _cmd_fill_batch
from .checks import REPORT_ALSO, _check_format, _check_input, _check_suffix
from .options import _fill_options, _naming, _pose_options, _progress, _say
from .qc import _qc_rows, _write_json, _write_report


def _cmd_fill(args) -> int:
    import torchfill
    from torchfill import batch

    if args.training:                                 # folders as the recordings they hold
        from torchfill.batch import expand
        args.training = [str(path) for path in expand(args.training)]
        if not args.training:
            raise ValueError("--training: no recordings found")
    if args.session and not (len(args.input) > 1 or args.out_dir):
        raise ValueError("--session fills a batch: give several inputs and --out-dir DIR")
    if len(args.input) > 1 or args.out_dir or args.ray:
        if args.axes or args.units:
            raise ValueError("--axes/--units: give one input and -o OUT.trc")
        return _cmd_fill_batch(args)
    src = Path(args.input[0])
    plan, out_path, backup = _plan_fill(args, src)     # every check before any file is read
    written_as = _trc_options(args, src, out_path)
    with plan:
        options = _fill_options(args, src)
        method = options.method
        plan.keep_templates()
        seq = torchfill.read(src, **_pose_options(args))
        if args.training:
            options = options.replace(training=[torchfill.read(path) for path in args.training])
        plan.confirm_inputs()
        n_missing = int(seq.mask.sum())
        _say(args, f"{seq}\nfilling {n_missing} missing samples with {method} ...")
        std_path = _std_path(args, out_path, method)
        want_std = bool(std_path or args.report or args.report_json
                        or args.rejected == "drop")            # the qc verdict uses it
        with _naming(src):
            filled = torchfill.fill(seq, options=options.replace(progress=_progress(args),
                                                                 return_std=want_std))
        filled = filled[0] if want_std else filled
        rows = None
        if args.rejected == "drop":
            filled, rows = batch.drop_rejected(seq, filled, method)
        if want_std:                                   # recorded in a C3D (docs/files.md)
            rows = batch.mark_verdicts(seq, filled, rows, method)
        plan.write_sequence(filled, out_path, backup=backup, **written_as)
        written = [out_path]
        if std_path:
            _write_std(filled, std_path, plan)
            written.append(std_path)
        if args.report or args.report_json:
            if rows is None:
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


def _trc_options(args, src: Path, out: Path) -> dict:
    """The TRC writer's ``axes`` and ``units`` from ``--axes``/``--units``, checked now."""
    if not (args.axes or args.units):
        return {}
    if out.suffix.lower() != ".trc":
        raise ValueError(f"{out}: --axes/--units write TRC files (OpenSim); found "
                         f"{out.suffix or 'no suffix'}")
    from torchfill.sequence import parse_axes

    try:
        if args.axes:
            parse_axes(args.axes)
    except ValueError as err:
        raise ValueError(f"{src}: --axes: {err}") from None
    return {k: v for k, v in (("axes", args.axes), ("units", args.units)) if v}


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
    std = _std_path(args, out, None)
    if std:
        _check_suffix(std, ".csv", "--std")
        plan.add_output(std, "--std file")
    if args.report:
        _check_suffix(Path(args.report), ".html", "--report", REPORT_ALSO)
        plan.add_output(args.report, "report")
    if getattr(args, "report_json", None):
        _check_suffix(Path(args.report_json), ".json", "--report-json")
        plan.add_output(args.report_json, "--report-json file")
    return out, backup


def _std_path(args, out: Path, method: str | None) -> Path | None:
    """Where the error estimate goes: ``--std``, else -- for the default method, whose estimate
    comes with its fill -- beside the output (:func:`torchfill.io.outputs.estimate_path`);
    None: not written (``--std none``, another method without ``--std``)."""
    import torchfill
    from torchfill.io.outputs import estimate_path

    if args.std:
        return None if args.std.lower() == "none" else Path(args.std)
    method = method or args.method or torchfill.default_method()
    return estimate_path(out) if method == "auto" else None


def _write_std(seq, path: Path, plan) -> None:
    """The error estimate (T, J) as CSV: a frame column, one column per marker, NaN where observed."""
    from torchfill import batch

    plan.write_text(path, batch.std_csv(seq), "--std file")


def _default_output(path: Path) -> Path:
    return path.with_name(f"{path.stem}_filled{path.suffix}")
