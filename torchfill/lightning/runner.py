"""Run an experiment config: plan -> execute -> report.

``run_experiment("experiments/tucker_table2.yaml")`` (or ``torchfill experiment CONFIG``, or
``python -m torchfill.lightning.runner CONFIG``) does three things:

1. :func:`plan` loads and validates the config (:func:`~torchfill.lightning.config.load_config`),
   reads each recording once to check that every grid point fits it, and lists the cases still to
   run (with ``resume=True``, those not finished in an earlier ``cases.csv``);
2. :func:`execute` runs them (in this process, or ``workers > 1`` local processes), each under a
   Lightning Trainer, appending each finished case's row to ``cases.csv`` at once;
3. :func:`report` writes ``table.md`` and the PNG plots from ``cases.csv``.

Results go to ``<results_dir>/<name>/`` (default ``results/`` beside the config file), per-iteration
logs to ``<results_dir>/../runs/<name>/`` (or ``<output>/runs`` when ``output`` is given).
"""
from __future__ import annotations

import argparse
import csv
import functools
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import rows as R
from .config import SELF, Case, Config, load_config


# -- one case (runs in a worker process, or in-process with workers=1) ----------------------------
@functools.lru_cache(maxsize=4)
def _config(path: str) -> Config:
    return load_config(path)


#: ``fill_case``'s options for the papers' protocols, what a case gets unless its config says
#: otherwise (``fill:``; a method's ``constraints: true``): the method's own fill, the whole
#: recording at once, no extrapolation limit; ``dtype`` is the config's. The case goes to
#: ``fill_case`` as a tensor on the config's ``device`` (no labels, no rate: segments, where a
#: method or the post-step uses them, are found in the data), or with ``fill: {sequence: true}``
#: as a MarkerSequence (labels, rate, units), as ``torchfill fill`` reads a file.
PAPER = {"constraints": False, "extrapolate": None, "window": None, "segments": None}


@dataclass
class CaseFill:
    """What :func:`solve_case` gives: the fill a row scores and how the solver got there."""

    filled: np.ndarray                 # (T, J, 3): the case's data, its gaps filled
    solvers: list                      # the fitted solver of each window
    stop: str = ""                     # why the (last) fit stopped
    solve_seconds: float = 0.0         # inside the solvers
    n_iter: int = 0
    curve: list = field(default_factory=list)   # truth-based metrics per step (showcase)


def run_case(config_path: str, case: Case, runs_dir: str, *, showcase: bool = False,
             progress: bool = False) -> dict[str, Any]:
    """Run one case; returns its ``cases.csv`` row (``status`` says "ok" or the error)."""
    from .. import metrics

    cfg = _config(config_path)
    row = R.key_row(case)
    start = time.perf_counter()
    try:
        rec, mask, rest = case_data(cfg, case.recording, case.point, case.seed)
        got = solve_case(cfg, case, rec, mask, rest, runs_dir=runs_dir, showcase=showcase,
                         progress=progress)
        final = metrics.score(got.filled, rec.truth, mask)
        solver = got.solvers[-1]
        row.update(solver=case.method.solver, **{k: final.get(k, "") for k in R.SCORE_METRICS},
                   n_iter=got.n_iter, rank=R.solver_rank(solver),
                   converged=all(s.converged_ for s in got.solvers), stop=got.stop,
                   solve_s=round(got.solve_seconds, 4), T=rec.shape[0], J=rec.shape[1],
                   status="ok")
        if showcase:
            _save_showcase(_showcase_path(runs_dir, case), case, rec, mask, got, solver.history_)
    except Exception as err:  # a failing method must not stop the grid; its row says why
        row.update(solver=case.method.solver, status=f"error: {type(err).__name__}: "
                   + " ".join(str(err).split())[:300])
    row["wall_s"] = round(time.perf_counter() - start, 4)
    return row


def fill_options(cfg: Config, case: Case, rec, rest):
    """The case's :class:`~torchfill.options.FillOptions` for ``fill_case`` -- and for
    ``torchfill.fill``, which takes the same: the method and its hyperparameters, ``training``,
    ``dtype`` and the protocol (:data:`PAPER`, the config's ``fill:``, the method's
    ``constraints``)."""
    from ..options import FillOptions

    params = dict(case.method.params)
    kwargs = {**PAPER, "dtype": cfg.dtype, **cfg.fill}
    kwargs.pop("sequence", None)
    if "constraints" in params:
        kwargs["constraints"] = bool(params.pop("constraints"))
    kwargs["training"] = _training(cfg, case, rec.labels, rest, params.pop("training", False))
    return FillOptions(case.method.solver, params=params, workers=1, **kwargs).checked()


def solve_case(cfg: Config, case: Case, rec, mask, rest, *, runs_dir: str | None = None,
               showcase: bool = False, progress: bool = False) -> CaseFill:
    """Fill one case through :func:`torchfill.filling.fill_case` -- the path of
    ``torchfill.fill`` -- with each window's solver driven by a Lightning Trainer (one
    ``solver.step()`` per training step; the truth goes to the evaluation callback only)."""
    import torch

    from ..filling import fill_case
    from ..sequence import MarkerSequence
    from .callbacks import Convergence, Evaluation, HistoryLogger
    from .data import CaseDataModule
    from .module import fit

    options = fill_options(cfg, case, rec, rest)
    X = np.where(mask[..., None], np.nan, rec.truth)
    data = (MarkerSequence(X, list(rec.labels), rate=rec.rate, units=rec.units)
            if cfg.fill.get("sequence") else torch.as_tensor(X, device=cfg.device))
    got = CaseFill(filled=X, solvers=[])
    loggers = _loggers(cfg, case, runs_dir) if runs_dir is not None else False
    accelerator = "gpu" if str(cfg.device).startswith("cuda") else "cpu"

    def solve(solver, Xw, missing, fit_data, callback, part):
        frames, markers = part
        truth = rec.truth[frames][:, markers.cpu().numpy()]
        dm = CaseDataModule(truth, missing, n_steps=solver.max_iter, X=Xw)
        stop, evaluation = Convergence(), Evaluation(every=1 if showcase else 0)
        module = fit(solver, dm, callbacks=[stop, HistoryLogger(), evaluation], logger=loggers,
                     progress=progress, accelerator=accelerator, data=fit_data)
        got.solvers.append(solver)
        got.stop, got.curve = stop.reason, evaluation.curve
        got.solve_seconds += module.solve_seconds
        got.n_iter += solver.n_iter_

    filled = fill_case(data, options, solve=solve)
    got.filled = np.asarray(filled.points if isinstance(filled, MarkerSequence)
                            else filled.cpu().numpy())
    return got


def case_data(cfg: Config, recording: str, point, seed: int):
    """``(recording, mask, rest)`` of a case: the recording (or its test segment), the gap mask
    and, with ``segments``, the rest of the recording (the self-training set; else None). Segment
    ``i``'s masks use seed ``1000 i + seed``."""
    from .data import cut_segment, load_recording, make_mask

    rec = load_recording(cfg.recording_path(recording), cfg.frames, cfg.projection)
    point, rest = dict(point), None
    if "segment" in point:
        index = point.pop("segment")
        rec, rest = cut_segment(rec, *cfg.segments, index)
        seed = 1000 * index + seed
    return rec, make_mask(cfg.protocol, rec.shape, point, seed), rest


def _loggers(cfg: Config, case: Case, runs_dir: str):
    """Per-case CSV logs of every iteration's history (and TensorBoard when installed)."""
    if not cfg.log:
        return False
    from pytorch_lightning.loggers import CSVLogger

    logger = [CSVLogger(str(Path(runs_dir) / "logs"), name=case.slug, version="")]
    try:
        from pytorch_lightning.loggers import TensorBoardLogger
        import tensorboard  # noqa: F401  (optional)
        logger.append(TensorBoardLogger(str(Path(runs_dir) / "tb"), name=case.slug, version=""))
    except ImportError:
        pass
    return logger


def _training(cfg: Config, case: Case, labels, rest, own=False):
    """The case's training data, arrays ``(T_i, J, 3)`` aligned by short label to ``labels``, for
    a method that takes them (``fit_data``): the config's ``training`` recordings, unless the
    method names its own (``own``: recording names; ``self``, the rest of the test recording
    outside its segment; ``~`` = none: the solver trains on what it is given); else None."""
    from ..solvers import get_solver
    from .data import align_training

    if "training" not in get_solver(case.method.solver).fit_data:
        return None
    names = cfg.training if own is False else own
    if names == SELF:
        return [part.copy() for part in rest]
    if not names:
        return None
    names = [names] if isinstance(names, str) else names
    return [align_training(cfg.recording_path(n), labels, cfg.projection) for n in names]


def _save_showcase(path: Path, case: Case, rec, mask, got: CaseFill, history) -> None:
    """The showcase case's arrays for the convergence and trajectory plots (evaluation only)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = sorted({k for h in history for k in h})
    hist = np.array([[h.get(k, np.nan) for k in keys] for h in history], dtype=float)
    curve_keys = sorted({k for c in got.curve for k in c})
    curve = np.array([[c[k] for k in curve_keys] for c in got.curve], dtype=float)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, filled=got.filled, truth=rec.truth, mask=mask,
                        labels=np.array(rec.labels), rate=rec.rate, history=hist,
                        history_keys=np.array(keys), curve=curve, curve_keys=np.array(curve_keys),
                        method=case.method.label, key=np.array(case.key))
    os.replace(tmp, path)


def threads_per_case() -> int:
    """Torch threads per case (env ``TORCHFILL_THREADS``, default 1): the matrices of one case are
    small, and multi-threaded LAPACK on small matrices is slower than one thread, much slower when the
    machine is busy (measured: 10x on the 2-core CI machine under load)."""
    value = os.environ.get("TORCHFILL_THREADS", "1")
    if not value.isdigit() or int(value) < 1:
        raise ValueError(f"TORCHFILL_THREADS expected a positive integer, found {value!r}")
    return int(value)


# -- plan -> execute -> report --------------------------------------------------------------------
@dataclass
class Plan:
    """What :func:`execute` runs and :func:`report` summarizes (see :func:`plan`)."""

    cfg: Config
    out_dir: Path
    runs_dir: Path
    header: list[str]
    cases: list[Case]                              # every case (after ``limit``)
    todo: list[Case]                               # those still to run
    done: dict[tuple, dict] = field(default_factory=dict)   # finished rows kept from cases.csv
    showcase: tuple = ()                           # (recording, point, seed) drawn in the plots
    notes: list[str] = field(default_factory=list)  # one line per recording

    @property
    def csv_path(self) -> Path:
        return self.out_dir / "cases.csv"


def plan(config_path, *, resume: bool = False, limit: int | None = None, output=None) -> Plan:
    """Validate the config, check every grid point against every recording, list the cases to run.

    ``output`` (relative to the working directory) replaces ``<results_dir>/<name>``; its
    per-iteration logs then go to ``<output>/runs``. Without ``resume`` an earlier ``cases.csv`` is
    discarded; with it, its finished rows are kept (failed cases and a stale showcase run again).
    """
    cfg = load_config(config_path)
    for m in cfg.skipped:
        print(f"{cfg.name}: method {m!r} is not registered; skipped", flush=True)
    if output is not None:
        out_dir = Path(os.path.abspath(output))
        runs_dir = out_dir / "runs"
    else:
        out_dir = cfg.results_dir / cfg.name
        runs_dir = cfg.results_dir.parent / "runs" / cfg.name
    _guard_results(cfg, out_dir)
    notes = _check_recordings(cfg)
    cases = cfg.cases()
    if limit is not None:
        cases = cases[:max(0, int(limit))]
    header = R.columns(cfg.keys)
    csv_path = out_dir / "cases.csv"
    done = _read_done(csv_path, header, cfg) if resume else {}
    showcase = _showcase_key(cfg)
    for case in cases:     # a showcase case whose plot arrays are missing or stale runs again
        if _is_showcase(case, showcase) and not _showcase_current(runs_dir, case):
            done.pop(case.key, None)
    todo = [c for c in cases if c.key not in done]
    return Plan(cfg, out_dir, runs_dir, header, cases, todo, done, showcase, notes)


def execute(p: Plan, *, workers: int = 1, ray_address: str | None = None) -> None:
    """Run ``p.todo``, appending each finished case's row to ``cases.csv`` (flushed at once); in
    ``workers`` local processes, or as Ray tasks with ``ray_address``."""
    cfg = p.cfg
    if workers < 1:
        raise ValueError(f"{cfg.path.name}: workers expected >= 1, found {workers}")
    p.out_dir.mkdir(parents=True, exist_ok=True)
    R.rewrite(p.csv_path, p.header, list(p.done.values()))
    if p.done:
        print(f"{cfg.name}: resuming, {len(p.cases) - len(p.todo)} of {len(p.cases)} cases "
              "already done", flush=True)
    todo = p.todo
    progress = workers == 1 and ray_address is None and sys.stdout.isatty()
    start = time.perf_counter()
    with open(p.csv_path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=p.header)

        def record(i: int, row: dict) -> None:
            writer.writerow(row)
            handle.flush()
            os.fsync(handle.fileno())
            metric = cfg.table["metric"]
            result = (f"{metric}={float(row[metric]):.4g}, {row['n_iter']} it"
                      if row["status"] == "ok" else row["status"])
            print(f"[{i}/{len(todo)}] {row['recording']} "
                  + " ".join(f"{k}={row[k]}" for k in cfg.keys)
                  + f" seed={row['seed']} {row['method']}: {result}, {row['wall_s']:.2f} s",
                  flush=True)

        args = [(str(cfg.path), c, str(p.runs_dir)) for c in todo]
        kwargs = [{"showcase": _is_showcase(c, p.showcase), "progress": progress} for c in todo]
        for i, (_, row) in enumerate(_run_cases(args, kwargs, workers, ray_address), 1):
            record(i, row)
    elapsed = time.perf_counter() - start
    print(f"{cfg.name}: {len(todo)} case(s) in {elapsed:.1f} s with {workers} worker(s)", flush=True)


def _run_cases(args: list[tuple], kwargs: list[dict], workers: int, ray_address: str | None):
    """``(i, row)`` of every case as it finishes, through the runtime's process pool
    (:func:`torchfill.runtime.pool.imap`); in this process with torch's threads set to
    :func:`threads_per_case` meanwhile."""
    from ..runtime.pool import imap

    threads = threads_per_case()

    def died(i: int, how: str) -> dict:
        row = R.key_row(args[i][1])
        row.update(solver=args[i][1].method.solver, status=f"error: the worker process died "
                   f"({how}) on both tries")
        return row

    if ray_address is not None or workers > 1:
        yield from imap(run_case, args, kwargs, workers=workers, ray_address=ray_address,
                        threads=threads, died=died)
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield from imap(run_case, args, kwargs)
    finally:
        torch.set_num_threads(before)


def report(p: Plan, *, workers: int = 1) -> Path:
    """``table.md`` and the plots from ``cases.csv``; returns the output folder."""
    from . import report as report_mod

    report_mod.write_report(p.cfg, R.read_rows(p.csv_path), p.out_dir, p.runs_dir, notes=p.notes,
                            skipped=p.cfg.skipped, command=_command(p.cfg, workers))
    return p.out_dir


def run_experiment(config_path, *, resume: bool = False, workers: int = 1, limit: int | None = None,
                   output=None, report_only: bool = False, ray_address: str | None = None) -> Path:
    """Run every case of ``config_path``: :func:`plan`, :func:`execute`, :func:`report`.

    Parameters
    ----------
    config_path : path to the YAML config.
    resume : keep the finished cases of an earlier ``cases.csv`` and run only the others.
    workers : number of local processes (each with one torch thread); 1 runs in this process.
    limit : run at most this many cases (the first ones, in config order).
    output : folder for the results (default ``<results_dir>/<name>``, ``results_dir`` defaulting
        to ``results/`` beside the config file); per-iteration logs go to ``<output>/runs``.
    report_only : run nothing; rewrite ``table.md`` and the plots from the ``cases.csv`` there.
    ray_address : run the cases as Ray tasks instead (``"auto"``, ``"local"`` or a cluster address;
        ``pip install torchfill[ray]``); every node needs the config's recordings at the same path.

    Returns
    -------
    Path : the output folder.
    """
    p = plan(config_path, resume=resume or report_only, limit=limit, output=output)
    for note in p.notes:
        print(note, flush=True)
    if report_only:
        if not p.csv_path.exists():
            raise ValueError(f"{p.cfg.path.name}: {p.csv_path} not found; nothing to report")
        print(f"{p.cfg.name}: report of {len(p.done)} finished case(s); {len(p.todo)} not run",
              flush=True)
    else:
        execute(p, workers=workers, ray_address=ray_address)
    return report(p, workers=workers)


def _guard_results(cfg: Config, out_dir: Path) -> None:
    """One line now if the results folder cannot be used, or a result file (cases.csv, table.md)
    would land on a recording or training file of the config (the guarded writer's checks)."""
    from ..io import FileFormatError
    from ..io.outputs import Outputs

    try:
        with Outputs() as guard:
            names = set(cfg.recordings) | set(cfg.training)
            for m in cfg.methods:
                own = m.params.get("training")
                if own not in (None, SELF):
                    names.update([own] if isinstance(own, str) else own)
            for name in sorted(names):
                guard.add_input(cfg.recording_path(name), "recording")
            folder = out_dir
            while not folder.exists() and not folder.is_symlink() and folder != folder.parent:
                folder = folder.parent               # the results folder is created later
            if folder == out_dir:
                for name in ("cases.csv", "table.md"):
                    guard.add_output(out_dir / name, "result file")
            else:
                guard.add_output(folder / out_dir.relative_to(folder).parts[0], "results folder",
                                 folder=True)
    except FileFormatError as err:
        raise ValueError(f"{cfg.path.name}: {err}") from None


def _check_recordings(cfg: Config) -> list[str]:
    """Read every recording once (errors name the config) and check each grid point fits it (and
    each of its segments); returns one note per recording."""
    from .data import load_recording

    notes = []
    for name in cfg.recordings:
        try:
            rec = load_recording(cfg.recording_path(name), cfg.frames, cfg.projection)
        except ValueError as err:
            raise ValueError(f"{cfg.path.name}: {' '.join(str(err).split())}") from None
        notes.append(rec.note())
        for point in cfg.points():
            try:
                case_data(cfg, name, point, cfg.seeds[0])
            except (TypeError, ValueError) as err:
                raise ValueError(f"{cfg.path.name}: {cfg.protocol} {dict(point)} on {name}: "
                                 f"{' '.join(str(err).split())}") from None
    return notes


def _showcase_key(cfg: Config) -> tuple:
    """The (recording, point, seed) whose fills and convergence curves are plotted."""
    sc = cfg.showcase
    recording = sc.get("recording", cfg.recordings[0])
    point = cfg.points()[0]
    point = tuple((k, sc.get(k, v)) for k, v in point)
    return recording, point, sc.get("seed", cfg.seeds[0])


def _is_showcase(case: Case, key: tuple) -> bool:
    return (case.recording, case.point, case.seed) == key


def _showcase_path(runs_dir, case: Case) -> Path:
    return Path(runs_dir) / "showcase" / f"{case.method.label}.npz"


def _showcase_current(runs_dir, case: Case) -> bool:
    path = _showcase_path(runs_dir, case)
    if not path.exists():
        return False
    try:
        with np.load(path) as z:
            return "key" in z.files and list(z["key"]) == list(case.key)
    except (OSError, ValueError):
        return False


def _read_done(path: Path, header: list[str], cfg: Config) -> dict[tuple, dict]:
    """Finished rows (status ok) of an earlier run, by case key; a torn last line is dropped. A
    file written before a column was added is accepted (the new cells stay empty)."""
    if not path.exists():
        return {}
    found = R.read_header(path) or []
    if not set(found) <= set(header) or found[:len(R.columns(cfg.keys)) - len(R.TAIL)] != \
            header[:len(header) - len(R.TAIL)]:
        raise ValueError(f"{cfg.path.name}: {path} has columns {found}, expected {header}; "
                         "run without --resume to start over")
    return {R.row_key(row, cfg.keys): row for row in R.read_rows(path) if row["status"] == "ok"}


def _command(cfg: Config, workers: int) -> str:
    try:
        rel = cfg.path.relative_to(Path.cwd())
    except ValueError:
        rel = cfg.path
    return f"torchfill experiment {rel}" + (f" --workers {workers}" if workers > 1 else "")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m torchfill.lightning.runner",
                                     description="Run an experiment config (YAML).")
    parser.add_argument("config")
    parser.add_argument("--resume", action="store_true", help="skip cases already in cases.csv")
    parser.add_argument("--workers", type=int, default=1, help="local processes (default 1)")
    parser.add_argument("--limit", type=int, default=None, help="run at most K cases")
    parser.add_argument("--output", default=None, help="results folder")
    parser.add_argument("--report-only", action="store_true",
                        help="only rewrite table.md and the plots from cases.csv")
    args = parser.parse_args(argv)
    try:
        out = run_experiment(args.config, resume=args.resume, workers=args.workers,
                             limit=args.limit, output=args.output, report_only=args.report_only)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
