"""``torchfill qc IN FILLED``: the per-gap verdicts of a fill, as text, HTML and JSON."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from .checks import _check_input, _check_suffix
from .options import _pose_options
from .terminal import _one_line


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
        std_path, source = _estimate_source(args)
        if std_path is not None:
            plan.add_input(std_path)
        plan.add_output(report, "qc report", hint="give another -o")
        if to_file:
            plan.add_output(args.json, "--json file")
        seq = torchfill.read(args.input, **_pose_options(args))
        filled = _read_filled(args.filled, args)
        if filled.points.shape != seq.points.shape:
            raise ValueError(f"{args.filled}: shape {filled.points.shape} differs from "
                             f"{args.input}'s {seq.points.shape}")
        std = _read_std(std_path, seq) if std_path is not None else filled.meta.get("std")
        if std_path is None and std is not None:
            source = f"the error estimate stored in {args.filled}"
        rows = _qc_rows(seq, filled, std, args.method or torchfill.default_method())
        if args.json == "-":
            print(json.dumps(qc.to_json(rows), indent=1))
        else:
            print(f"estimate: {source}")
            print(qc.format_table(rows, seq.units))
        _write_report(seq, filled, report, str(args.filled), rows, std, plan=plan)
        if to_file:
            _write_json(rows, Path(args.json), plan)
    if not args.quiet:
        print(f"{qc.summary(rows, qc.unfilled_samples(filled.points))} -> {report}",
              file=sys.stderr if args.json == "-" else sys.stdout)
    return 0


def _estimate_source(args) -> tuple[Path | None, str]:
    """The std file the verdicts use and a line saying where it came from: ``--std``, else the
    file 'fill' writes beside FILLED when it is not older than FILLED (a later fill of FILLED
    without an estimate leaves an older one behind, which is not this fill's)."""
    from torchfill.io.outputs import estimate_path

    if args.std:
        return Path(args.std), f"{args.std} (--std)"
    side = estimate_path(args.filled)
    if not side.is_file():
        return None, (f"none found ({side} is absent): verdicts from the plausibility tests only; "
                      "'torchfill fill' with the default method writes it beside its output")
    filled = Path(args.filled)
    if not filled.is_dir() and side.stat().st_mtime_ns < filled.stat().st_mtime_ns:
        return None, (f"none: {side} is older than {args.filled} (not this fill's), not used; "
                      "verdicts from the plausibility tests only")
    return side, f"{side} (written by 'torchfill fill' beside {args.filled})"


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
