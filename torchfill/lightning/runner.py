"""Run an experiment config end to end: every case under a Lightning Trainer, results as they finish.

``run_experiment("experiments/tucker_table2.yaml")`` (or ``torchfill experiment CONFIG``, or
``python -m torchfill.lightning.runner CONFIG``) expands the config into cases (recording x grid point
x seed x method), runs each (in parallel over local processes with ``workers > 1``), appends each
finished case to ``cases.csv`` at once (so ``resume=True`` skips finished cases after an
interruption), then writes ``table.md`` and the PNG plots. Per-iteration logs go under
``experiments/runs/<name>/`` (not committed); the small results under ``experiments/results/<name>/``.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import csv
import functools
import multiprocessing
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from .config import REPO_ROOT, Case, Config, load_config

SCORE_METRICS = ["rmse", "ave", "std", "rmse_missing", "gap_error"]
TAIL = ["solver", *SCORE_METRICS, "n_iter", "converged", "stop", "solve_s", "wall_s", "T", "J",
        "status"]


# -- one case (runs in a worker process, or in-process with workers=1) ----------------------------
@functools.lru_cache(maxsize=4)
def _config(path: str) -> Config:
    return load_config(path)


def run_case(config_path: str, case: Case, runs_dir: str, *, showcase: bool = False,
             progress: bool = False) -> dict[str, Any]:
    """Run one case; returns its ``cases.csv`` row (``status`` says "ok" or the error)."""
    from ..solvers import get_solver
    from .callbacks import Convergence, Evaluation, HistoryLogger
    from .data import CaseDataModule, align_training, load_recording, make_mask
    from .module import fit

    import torch

    cfg = _config(config_path)
    row = _key_row(cfg, case)
    start = time.perf_counter()
    try:
        rec = load_recording(cfg.recording_path(case.recording), cfg.frames, cfg.projection)
        mask = make_mask(cfg.protocol, rec.shape, dict(case.point), case.seed)
        params = _training_params(cfg, case, rec.labels, get_solver, align_training)
        solver = get_solver(case.method.solver, **params)
        dm = CaseDataModule(rec.truth, mask, n_steps=solver.max_iter,
                            dtype=getattr(torch, cfg.dtype), device=cfg.device)
        evaluation = Evaluation(every=1 if showcase else 0)
        stop = Convergence()
        callbacks = [stop, HistoryLogger(), evaluation]
        logger = False
        if cfg.log:
            from pytorch_lightning.loggers import CSVLogger
            logger = [CSVLogger(str(Path(runs_dir) / "logs"), name=case.slug, version="")]
            try:
                from pytorch_lightning.loggers import TensorBoardLogger
                import tensorboard  # noqa: F401  (optional)
                logger.append(TensorBoardLogger(str(Path(runs_dir) / "tb"), name=case.slug, version=""))
            except ImportError:
                pass
        accelerator = "gpu" if str(cfg.device).startswith("cuda") else "cpu"
        module = fit(solver, dm, callbacks=callbacks, logger=logger, progress=progress,
                     accelerator=accelerator)
        row.update(solver=case.method.solver, **{k: evaluation.final.get(k, "") for k in SCORE_METRICS},
                   n_iter=solver.n_iter_, converged=solver.converged_, stop=stop.reason,
                   solve_s=round(module.solve_seconds, 4), T=rec.shape[0], J=rec.shape[1],
                   status="ok")
        if showcase:
            _save_showcase(_showcase_path(runs_dir, case), case, rec, mask, evaluation,
                           solver.history_)
    except Exception as err:  # a failing method must not stop the grid; its row says why
        row.update(solver=case.method.solver, status=f"error: {type(err).__name__}: "
                   + " ".join(str(err).split())[:300])
    row["wall_s"] = round(time.perf_counter() - start, 4)
    return row


def _training_params(cfg: Config, case: Case, labels, get_solver, align_training) -> dict:
    """The method's hyperparameters, with ``training`` as arrays ``(T_i, J, 3)`` aligned by short
    label to ``labels``: the config's ``training`` recordings for every solver that declares
    ``training``, unless the method sets its own (recording names, or ``~`` = none, which leaves
    the solver to train on the recording itself)."""
    params = dict(case.method.params)
    own = "training" in params
    declared = "training" in type(get_solver(case.method.solver)).declared_params()
    if not own and not (cfg.training and declared):
        return params
    names = params["training"] if own else cfg.training
    if names is not None:
        names = [names] if isinstance(names, str) else names
        params["training"] = [align_training(cfg.recording_path(n), labels, cfg.projection)
                              for n in names]
    return params


def _save_showcase(path: Path, case: Case, rec, mask, evaluation, history) -> None:
    """The showcase case's arrays for the convergence and trajectory plots (evaluation only)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = sorted({k for h in history for k in h})
    hist = np.array([[h.get(k, np.nan) for k in keys] for h in history], dtype=float)
    curve_keys = sorted({k for c in evaluation.curve for k in c})
    curve = np.array([[c[k] for k in curve_keys] for c in evaluation.curve], dtype=float)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, filled=evaluation.filled, truth=rec.truth, mask=mask,
                        labels=np.array(rec.labels), rate=rec.rate, history=hist,
                        history_keys=np.array(keys), curve=curve, curve_keys=np.array(curve_keys),
                        method=case.method.label, key=np.array(case.key))
    os.replace(tmp, path)


def _key_row(cfg: Config, case: Case) -> dict[str, Any]:
    return {"recording": case.recording, **dict(case.point), "seed": case.seed,
            "method": case.method.label}


def threads_per_case() -> int:
    """Torch threads per case (env ``TORCHFILL_THREADS``, default 1): the matrices of one case are
    small, and multi-threaded LAPACK on small matrices is slower than one thread, much slower when the
    machine is busy (measured: 10x on the 2-core CI machine under load)."""
    value = os.environ.get("TORCHFILL_THREADS", "1")
    if not value.isdigit() or int(value) < 1:
        raise ValueError(f"TORCHFILL_THREADS expected a positive integer, found {value!r}")
    return int(value)


class _ThreadEnv:
    """Set ``OMP/OPENBLAS/MKL_NUM_THREADS`` (unless the user set them) while worker processes start,
    so NumPy/SciPy's BLAS in a worker does not spin extra threads against the other workers."""

    NAMES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

    def __init__(self, threads: int) -> None:
        self.threads, self.saved = str(threads), {}

    def __enter__(self):
        for name in self.NAMES:
            if name not in os.environ:
                self.saved[name] = None
                os.environ[name] = self.threads
        return self

    def __exit__(self, *exc) -> None:
        for name in self.saved:
            os.environ.pop(name, None)


def _init_worker(threads: int = 1) -> None:
    import torch

    torch.set_num_threads(threads)


# -- the experiment -------------------------------------------------------------------------------
def run_experiment(config_path, *, resume: bool = False, workers: int = 1, limit: int | None = None,
                   output=None) -> Path:
    """Run every case of ``config_path``; returns the output folder.

    Parameters
    ----------
    config_path : path to the YAML config.
    resume : keep the finished cases of an earlier ``cases.csv`` and run only the others.
    workers : number of local processes (each with one torch thread); 1 runs in this process.
    limit : run at most this many cases (the first ones, in config order).
    output : folder for the results (default ``experiments/results/<name>``); per-iteration logs go
        to ``experiments/runs/<name>`` (or ``<output>/runs`` when ``output`` is given).
    """
    from ..solvers import available, get_solver

    cfg = load_config(config_path)
    if workers < 1:
        raise ValueError(f"{cfg.path.name}: workers expected >= 1, found {workers}")
    out_dir = Path(output) if output is not None else REPO_ROOT / "experiments" / "results" / cfg.name
    runs_dir = out_dir / "runs" if output is not None else REPO_ROOT / "experiments" / "runs" / cfg.name
    out_dir.mkdir(parents=True, exist_ok=True)

    methods, skipped = [], []
    for m in cfg.methods:
        if m.solver not in available():
            skipped.append(m.label)
            print(f"{cfg.name}: method {m.label!r} ({m.solver}) is not registered; skipped", flush=True)
            continue
        try:
            get_solver(m.solver, **{k: v for k, v in m.params.items() if k != "training"})
            names = m.params.get("training") or []
            for name in [names] if isinstance(names, str) else names:
                if not isinstance(name, str) or not cfg.recording_path(name).is_file():
                    raise ValueError(f"training recording {name!r} not found in {cfg.data_dir}")
        except ValueError as err:
            raise ValueError(f"{cfg.path.name}: methods.{m.label}: {err}") from None
        methods.append(m)
    notes = _check_recordings(cfg)
    for note in notes:
        print(note, flush=True)

    cases = cfg.cases(methods)
    if limit is not None:
        cases = cases[:max(0, int(limit))]
    columns = ["recording", *cfg.grid, "seed", "method", *TAIL]
    csv_path = out_dir / "cases.csv"
    done = _read_done(csv_path, columns, cfg) if resume else {}
    showcase = _showcase_key(cfg)
    for case in cases:     # a showcase case whose plot arrays are missing or stale runs again
        if _is_showcase(case, showcase) and not _showcase_current(runs_dir, case):
            done.pop(case.key, None)
    if not resume and csv_path.exists():
        csv_path.unlink()
    _rewrite(csv_path, columns, list(done.values()))
    todo = [c for c in cases if c.key not in done]
    if resume and done:
        print(f"{cfg.name}: resuming, {len(cases) - len(todo)} of {len(cases)} cases already done",
              flush=True)

    progress = workers == 1 and sys.stdout.isatty()
    start = time.perf_counter()
    with open(csv_path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)

        def record(i: int, row: dict) -> None:
            writer.writerow(row)
            handle.flush()
            os.fsync(handle.fileno())
            metric = cfg.table["metric"]
            result = (f"{metric}={float(row[metric]):.4g}, {row['n_iter']} it"
                      if row["status"] == "ok" else row["status"])
            print(f"[{i}/{len(todo)}] {row['recording']} "
                  + " ".join(f"{k}={row[k]}" for k in cfg.grid)
                  + f" seed={row['seed']} {row['method']}: {result}, {row['wall_s']:.2f} s",
                  flush=True)

        args = [(str(cfg.path), c, str(runs_dir)) for c in todo]
        show = [_is_showcase(c, showcase) for c in todo]
        threads = threads_per_case()
        if workers == 1:
            import torch

            before = torch.get_num_threads()
            torch.set_num_threads(threads)
            try:
                for i, (a, s) in enumerate(zip(args, show), 1):
                    record(i, run_case(*a, showcase=s, progress=progress))
            finally:
                torch.set_num_threads(before)
        else:
            ctx = multiprocessing.get_context("spawn")
            pool_env = _ThreadEnv(threads)     # BLAS/OpenMP threads of the workers (read at start)
            with pool_env, cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                                                  initargs=(threads,)) as pool:
                futures = [pool.submit(run_case, *a, showcase=s) for a, s in zip(args, show)]
                try:
                    for i, fut in enumerate(cf.as_completed(futures), 1):
                        record(i, fut.result())
                except BaseException:
                    for fut in futures:
                        fut.cancel()
                    raise
    elapsed = time.perf_counter() - start
    print(f"{cfg.name}: {len(todo)} case(s) in {elapsed:.1f} s with {workers} worker(s)", flush=True)

    from . import report

    rows = _read_rows(csv_path)
    report.write_report(cfg, rows, out_dir, runs_dir, notes=notes, skipped=skipped,
                        command=_command(cfg, workers))
    return out_dir


def _check_recordings(cfg: Config) -> list[str]:
    """Load every recording once (errors name the config), check each grid point fits it."""
    from .data import load_recording, make_mask

    notes = []
    for name in cfg.recordings + cfg.training:
        path = cfg.recording_path(name)
        if not path.is_file():
            raise ValueError(f"{cfg.path.name}: recording {name} not found in {cfg.data_dir}")
    for name in cfg.recordings:
        try:
            rec = load_recording(cfg.recording_path(name), cfg.frames, cfg.projection)
        except ValueError as err:
            raise ValueError(f"{cfg.path.name}: {err}") from None
        notes.append(rec.note())
        for point in cfg.points():
            try:
                make_mask(cfg.protocol, rec.shape, dict(point), cfg.seeds[0])
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


def _read_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        n = len(reader.fieldnames or [])
        return [r for r in reader if None not in r and None not in r.values() and len(r) == n]


def _read_done(path: Path, columns: list[str], cfg: Config) -> dict[tuple, dict]:
    """Finished rows (status ok) of an earlier run, by case key; a torn last line is dropped."""
    if not path.exists():
        return {}
    with open(path, newline="") as handle:
        header = next(csv.reader(handle), None)
    if header != columns:
        raise ValueError(f"{cfg.path.name}: {path} has columns {header}, expected {columns}; "
                         "run without --resume to start over")
    done = {}
    for row in _read_rows(path):
        if row["status"] == "ok":
            key = (row["recording"], *(row[k] for k in cfg.grid), row["seed"], row["method"])
            done[key] = row
    return done


def _rewrite(path: Path, columns: list[str], rows: list[dict]) -> None:
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


def _command(cfg: Config, workers: int) -> str:
    try:
        rel = cfg.path.relative_to(REPO_ROOT)
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
    args = parser.parse_args(argv)
    try:
        out = run_experiment(args.config, resume=args.resume, workers=args.workers,
                             limit=args.limit, output=args.output)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
