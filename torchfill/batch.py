"""Many recordings at once: ``torchfill fill A.c3d B.c3d ... --out-dir DIR``.

:func:`expand` turns files, folders and glob patterns into input paths; :func:`fill_file` fills
one file and returns a summary row instead of raising (a failing file never stops the others);
:func:`run` fills the jobs in this process, in ``workers`` processes, or as Ray tasks
(``ray_address``: ``"auto"``, ``"local"`` or a cluster address; ``pip install torchfill[ray]``),
yielding each row as its file finishes.
"""
from __future__ import annotations

import glob
import os
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .options import FillOptions

SUFFIXES = (".c3d", ".trc", ".npy", ".npz", ".csv")


@dataclass(frozen=True)
class Job:
    """One file to fill: where from, where to, and how (``options``: the fill's options; ``report``
    and ``std``: the side outputs of this file, as ``torchfill fill --report/--std`` writes them)."""

    input: str
    output: str
    options: FillOptions = field(default_factory=FillOptions)
    training: tuple[str, ...] = ()
    report: str | None = None
    std: str | None = None
    read_options: dict = field(default_factory=dict)
    #: training recordings already read (the other trials of a ``--session``: see :func:`session`)
    session: tuple = ()
    #: the gaps the qc verdict rejects: "keep" them, or "drop" them (see :func:`drop_rejected`)
    rejected: str = "keep"


def expand(items: list[str]) -> list[Path]:
    """Files as given; folders as their recordings (sorted, not recursive); patterns via glob.
    A name that is neither an existing path nor a matching pattern is kept (it fails, reported)."""
    paths: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir() and not any(path.glob("*_keypoints.json")):
            paths.extend(sorted(p for p in path.iterdir()
                                if p.is_file() and p.suffix.lower() in SUFFIXES))
        elif not path.exists() and glob.has_magic(item):
            paths.extend(Path(p) for p in sorted(glob.glob(item, recursive=True)))
        else:
            paths.append(path)
    return list(dict.fromkeys(paths))


def outputs(inputs: list[Path], out_dir: Path) -> list[Path]:
    """``out_dir / name`` for each input; refuses to overwrite an input or write one name twice
    (the command line checks more through :class:`torchfill.io.outputs.Outputs`)."""
    outs = [out_dir / p.name for p in inputs]
    seen: dict[Path, Path] = {}
    for src, dst in zip(inputs, outs):
        if os.path.realpath(dst) == os.path.realpath(src):
            raise ValueError(f"{src}: --out-dir would overwrite the input; choose another folder")
        if dst in seen:
            raise ValueError(f"{src}: same output name as {seen[dst]} in {out_dir}")
        seen[dst] = src
    return outs


def side_name(pattern: str, src: Path, kind: str) -> Path:
    """A side output's name for ``src``: ``pattern`` with ``{stem}``/``{name}``, or a folder
    (ending in a separator) holding ``<stem>.qc.html`` (report) / ``<stem>_std.csv`` (std)."""
    stem = src.name if src.is_dir() else src.stem
    if "{stem}" in pattern or "{name}" in pattern:
        return Path(pattern.replace("{stem}", stem).replace("{name}", src.name))
    return Path(pattern) / (f"{stem}.qc.html" if kind == "report" else f"{stem}_std.csv")


def std_csv(seq) -> str:
    """The error estimate ``meta["std"]`` (T, J) as CSV text: a frame column, one column per
    marker, NaN where observed."""
    import io

    import numpy as np

    std = seq.meta["std"]
    first = int(getattr(seq, "first_frame", 0) or 0)        # frames numbered as the file does
    table = np.column_stack([first + np.arange(std.shape[0]), std])
    out = io.StringIO()
    np.savetxt(out, table, delimiter=",", fmt="%.6g", comments="",
               header=",".join(["frame", *seq.labels]))
    return out.getvalue()


def qc_rows(seq, filled, std=None, method: str | None = None) -> list[dict]:
    """The qc verdict rows of a fill (:func:`torchfill.qc.gap_table`): frames numbered as the
    file does, in its units; ``method`` made the fill (a spatial method's trial-end fills in
    frames with enough markers seen are not extrapolations in time)."""
    from . import qc
    from .solvers import base

    spatial = bool(getattr(base._REGISTRY.get(method or ""), "spatial", False))
    return qc.gap_table(seq.points, filled.points, seq.rate, seq.labels, std,
                        units=seq.units, first_frame=int(getattr(seq, "first_frame", 0) or 0),
                        support=filled.meta.get("support"), spatial=spatial,
                        prior=seq.meta.get("filled"))


def mark_verdicts(seq, filled, rows=None, method: str | None = None) -> list[dict]:
    """Set ``filled.meta["verdict"]``, the code of each filled sample's qc verdict (``rows``, or
    those of :func:`qc_rows` with the fill's estimate ``meta["std"]``; codes the input file
    recorded kept where no gap of this fill is), which a C3D writer records in the file
    (:mod:`torchfill.io.c3d_marks`). Returns the rows."""
    from . import qc

    if rows is None:
        rows = qc_rows(seq, filled, filled.meta.get("std"), method)
    filled.meta["verdict"] = qc.sample_verdicts(rows, filled.points, seq.meta.get("verdict"))
    return rows


def drop_rejected(seq, filled, method: str | None = None):
    """``(filled, rows)``: the fill with the samples of the gaps its qc verdict rejects left NaN
    (:func:`torchfill.qc.drop_rejected`; one warning counts and names them), and the verdicts of
    the fill returned. ``filled.meta["std"]`` (the fill's estimate) is used and kept in step."""
    import numpy as np

    from . import qc
    from .unfilled import UnfilledWarning

    rows = qc_rows(seq, filled, filled.meta.get("std"), method)
    F, S, dropped = qc.drop_rejected(filled.points, rows, filled.meta.get("std"))
    if not dropped:
        return filled, rows
    out = filled.with_points(F)
    if S is not None:
        out.meta["std"] = S
    if out.meta.get("filled") is not None:
        out.meta["filled"] = np.asarray(out.meta["filled"], dtype=bool) & np.isfinite(F).all(axis=2)
    count = sum(r["filled_frames"] for r in dropped)
    names = sorted({r["marker"] for r in dropped})
    warnings.warn(f"{count} filled sample(s) of {len(dropped)} gap(s) the qc verdict rejects "
                  f"left NaN ({', '.join(names[:8])}{' ...' if len(names) > 8 else ''}; "
                  "rejected='keep' writes them)", UnfilledWarning, stacklevel=2)
    return out, qc_rows(seq, out, S, method)


def write_report(seq, filled, path, title: str, rows=None, plan=None, *, std=None,
                 method: str | None = None) -> None:
    """The qc HTML report of a fill, through the run's guarded writer ``plan``."""
    from . import qc

    std = std if std is not None else filled.meta.get("std")
    rows = rows if rows is not None else qc_rows(seq, filled, std, method)
    html = qc.html_report(seq.points, filled.points, rows, title=title, rate=seq.rate,
                          units=seq.units, names=seq.labels, std=std,
                          first_frame=int(getattr(seq, "first_frame", 0) or 0))
    if plan is None:
        from .io.outputs import Outputs
        with Outputs() as plan:
            plan.write_text(path, html, "report")
    else:
        plan.write_text(path, html, "report")


def fill_file(job: Job) -> dict:
    """Read, fill and write one file with its side outputs, all through one guarded writer; a
    summary row (``error`` set on failure; then nothing of this file is written)."""
    import torchfill
    from .io.outputs import Outputs

    row = {"file": job.input, "output": job.output, "frames": 0, "markers": 0, "missing": 0,
           "filled": 0, "seconds": 0.0, "warnings": [], "error": None, "outputs": []}
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught, Outputs() as plan:
            warnings.simplefilter("always")
            plan.add_input(job.input, template=True)
            for path in job.training:
                plan.add_input(path, "training")
            plan.add_output(job.output, folder=not Path(job.output).suffix)
            for path, what in ((job.std, "--std file"), (job.report, "report")):
                if path:
                    plan.add_output(path, what)
            plan.keep_templates()
            seq = torchfill.read(job.input, **job.read_options)
            row.update(frames=seq.n_frames, markers=seq.n_markers, missing=int(seq.mask.sum()))
            options = job.options
            if job.training or job.session:
                options = options.replace(training=[*job.session,
                                                    *(torchfill.read(p) for p in job.training)])
            plan.confirm_inputs()
            want_std = bool(job.std or job.report or job.rejected == "drop")   # qc uses it
            out = torchfill.fill(seq, options=options.replace(return_std=want_std))
            out = out[0] if want_std else out
            method = job.options.method or torchfill.default_method()
            rows = None
            if job.rejected == "drop":
                out, rows = drop_rejected(seq, out, method)
            if want_std:
                mark_verdicts(seq, out, rows, method)
            plan.write_sequence(out, job.output)
            row["outputs"].append(job.output)
            if job.std:
                plan.write_text(job.std, std_csv(out), "--std file")
                row["outputs"].append(job.std)
            if job.report:
                write_report(seq, out, job.report, job.input, plan=plan, method=method)
                row["outputs"].append(job.report)
        row["filled"] = row["missing"] - int(out.mask.sum())
        row["warnings"] = _texts(caught)
    except Exception as err:  # reported per file; the batch goes on
        text = " ".join(str(err).split()) or type(err).__name__
        if not isinstance(err, (ValueError, OSError, KeyError)):
            text = f"internal error: {type(err).__name__}: {text}"
        row["error"] = text if text.startswith(job.input) else f"{job.input}: {text}"
        row["outputs"] = []                          # the guarded writer wrote none of them
    row["seconds"] = round(time.perf_counter() - start, 3)
    return row


#: ``--session`` inputs up to this many frames stay whole in the pool: ``auto``'s cross-trial
#: hold-out lays a trial's gap pattern on a window of another trial at least as long, and the fill
#: then stacks its training frames from the whole trials as ``fill(training=)`` does. Cut to their
#: share (200 frames each of the 400-frame trials of ``python -m benchmarks session``), the
#: trials left the hold-out out, and a trial's fill erred 57.4 mm where the whole trials gave 18.7.
WHOLE = 2000


def session(inputs: list[Path], read_options: list[dict] | None = None) -> dict[Path, tuple]:
    """``--session``: per input, the other inputs of its marker set as training recordings. Each
    input is read once; one longer than ``WHOLE`` frames is cut to its share of the training frames
    one fill stacks (:data:`torchfill.solvers.session.TRAINING_FRAMES` over the others of its
    marker set, in evenly spread runs). A batch holds one pool per marker set, not a copy per pair
    of files, at most ``WHOLE`` frames of each file, and a fill stacks the same number of training
    frames whatever the size of the session. An input that cannot be read is left out of the pool
    (its own fill reports the error)."""
    import numpy as np

    import torchfill
    from .solvers.session import BLOCK, TRAINING_FRAMES, spread_runs

    read_options = read_options or [{}] * len(inputs)
    groups: dict[frozenset, list] = {}
    for path, options in zip(inputs, read_options):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                seq = torchfill.read(path, **options)
        except Exception:  # noqa: BLE001 -- reported by the file's own fill
            continue
        groups.setdefault(frozenset(seq.short_labels()), []).append((path, seq))
    pool: dict[Path, tuple] = {}
    for members in groups.values():
        share = TRAINING_FRAMES // max(1, len(members) - 1)
        cut = []
        for path, seq in members:
            if seq.n_frames <= WHOLE:
                part = seq.with_points(seq.points)
            else:
                seen = np.isfinite(seq.points).all(axis=2).any(axis=1)    # frames with a marker seen
                part = seq.with_points(np.asarray(spread_runs(seq.points[seen], max(BLOCK, share),
                                                              BLOCK)))
            part.meta = {}
            cut.append((path, part))
        for path, _ in members:
            pool[path] = tuple(part for other, part in cut if other != path)
    return pool


def _texts(caught) -> list[str]:
    """Each warning's text once, in order (deprecations left out)."""
    return list(dict.fromkeys(" ".join(str(w.message).split()) for w in caught
                              if not issubclass(w.category, (DeprecationWarning,
                                                             PendingDeprecationWarning))))


def run(jobs: list[Job], workers: int = 1, ray_address: str | None = None) -> Iterator[dict]:
    """Fill every job; yields the rows as files finish (in any order), through the runtime's
    process pool (:func:`torchfill.runtime.pool.imap`: ``workers`` processes of one thread each,
    or Ray tasks with ``ray_address``). A worker that dies costs only its file: the file is tried
    once more in a new worker, then reported failed, and the batch goes on. Closing the generator
    (or Ctrl-C) stops at once, and no worker is left."""
    from .io.outputs import sweep
    from .runtime.pool import imap

    def cleanup(i: int) -> None:
        for path in (jobs[i].output, jobs[i].report, jobs[i].std):
            if path:
                sweep(path)

    def died(i: int, how: str) -> dict:
        job = jobs[i]
        return {"file": job.input, "output": job.output, "frames": 0, "markers": 0,
                "missing": 0, "filled": 0, "seconds": 0.0, "warnings": [], "outputs": [],
                "error": f"{job.input}: the worker process died ({how}) on both tries; not filled"}

    def retried(i: int, row: dict, how: str) -> dict:
        if not row["error"]:
            row["warnings"].append(f"the first worker process died ({how}); filled on the "
                                   "second try")
        return row

    for _, row in imap(fill_file, [(job,) for job in jobs], workers=workers,
                       ray_address=ray_address, died=died, retried=retried, cleanup=cleanup):
        yield row


def table(rows: list[dict]) -> str:
    """The end-of-batch summary, one line per file in input order."""
    head = f"{'file':<40} {'frames':>7} {'markers':>7} {'missing':>8} {'filled':>8} {'seconds':>8}  status"
    lines = [head, "-" * len(head)]
    for row in rows:
        name = Path(row["file"]).name
        status = "FAILED" if row["error"] else ("ok" if not row["warnings"] else
                                                f"ok, {len(row['warnings'])} warning(s)")
        lines.append(f"{name[-40:]:<40} {row['frames']:>7} {row['markers']:>7} {row['missing']:>8} "
                     f"{row['filled']:>8} {row['seconds']:>8.2f}  {status}")
    notes = []
    for row in rows:
        name = Path(row["file"]).name
        if row.get("outputs"):
            notes.append(f"{name} -> {', '.join(map(str, row['outputs']))}")
        notes.extend(f"{name}: warning: {text}" for text in row["warnings"])
        if row["error"]:
            notes.append(f"{name}: FAILED: {row['error']}")
    failed = sum(1 for row in rows if row["error"])
    lines.extend(notes)
    lines.append(f"{len(rows) - failed} of {len(rows)} file(s) filled"
                 + (f", {failed} failed" if failed else ""))
    return "\n".join(lines)


__all__ = ["Job", "SUFFIXES", "expand", "fill_file", "outputs", "run", "session",
           "side_name", "std_csv", "table", "write_report"]
